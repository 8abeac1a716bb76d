"""`v2i eval-tracker`: the RSU perception chain on a scenario's camera sequence, scored on truth.

Registered through the `v2i.commands` entry points (pyproject.toml). Module-level imports stay
light: the master's CLI imports this file to build its parser, so torch, pybullet and the world
are imported only when the command runs.

Exit codes as the rest of `v2i`: 0 success, 1 failure while running, 2 bad input.
"""
from __future__ import annotations

import argparse
import json
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    k = sub.add_parser("eval-tracker", help="detect, project and track the scenario's camera sequence; "
                                           "position/speed/heading errors against the simulator's truth")
    k.add_argument("--scenario", required=True, help="scenario file with a [world] camera (e.g. the IMA case study)")
    k.add_argument("--detector", default="torch", help="backend: torch or onnx (default torch, shipped weights)")
    k.add_argument("--weights", help="weights file (default the shipped ones)")
    k.add_argument("--threads", type=int, default=None)
    k.add_argument("--start", type=float, help="first frame time (default the scenario's start)")
    k.add_argument("--stop", type=float, help="last frame time (default the scenario's stop)")
    k.add_argument("--rate", type=float, help="frame rate in Hz (default the camera's)")
    k.add_argument("--near", type=float, default=60.0, help="score vehicles within this range of the camera (m)")
    k.add_argument("--min-age", type=float, default=1.0, help="score tracks older than this (s)")
    k.add_argument("--motion", default="cv", choices=("cv", "ctrv"),
                   help="tracker motion model: constant velocity (default) or constant turn rate and velocity")
    k.add_argument("--json", action="store_true", help="print JSON instead of a table")
    k.set_defaults(func=_cmd_eval_tracker)


def _cmd_eval_tracker(args) -> int:
    from master.scenario import ScenarioError
    from rsu_app.perception.detector import DetectorError, make_detector
    from rsu_app.perception.tracker import Tracker

    try:
        opts: dict = {"weights": args.weights}
        if args.threads is not None:
            opts["threads"] = args.threads
        det = make_detector(args.detector, **opts)  # first: a missing backend is said before the world loads
        from evaluation.tracker_sequence import evaluate_sequence

        rep = evaluate_sequence(args.scenario, det, start=args.start, stop=args.stop, rate_hz=args.rate,
                                near_m=args.near, min_age=args.min_age, tracker=Tracker(motion=args.motion))
    except (DetectorError, ScenarioError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(rep.to_dict(), indent=2) if args.json else rep.table())
    return 0
