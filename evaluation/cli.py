"""`v2i eval-tracker`: the RSU perception chain on a scenario's camera sequence, scored on truth.

Registered through the `v2i.commands` entry points (pyproject.toml). Module-level imports stay
light: the master's CLI imports this file to build its parser, so torch, pybullet and the world
are imported only when the command runs.

By default it scores the chain the RSU app runs (`--chain app`: its PerceptionStage at the
operating point of `rsu_app.config.Settings`, which the override flags change, each checked as
the app checks its config); `--chain tracker` scores the bare detector -> ground -> Kalman
tracker chain for comparison.

Exit codes as the rest of `v2i`: 0 success, 1 failure while running, 2 bad input.
"""
from __future__ import annotations

import argparse
import json
import sys

# flag -> (argparse dest, the Settings key it overrides); values go through the app's own config checks
OVERRIDES = {
    "--score-threshold": ("score_threshold", "detector.score_threshold"),
    "--confirm-hits": ("confirm_hits", "tracker.confirm_hits"),
    "--confirm-window": ("confirm_window", "tracker.confirm_window"),
    "--max-missed": ("max_missed", "tracker.max_missed"),
    "--gate": ("gate", "tracker.gate"),
    "--meas-std": ("meas_std", "tracker.meas_std"),
    "--motion": ("motion", "tracker.motion"),
}
APP_ONLY = ("--score-threshold",)  # the tracker chain keeps the detector's own threshold


def add_parser(sub: argparse._SubParsersAction) -> None:
    k = sub.add_parser("eval-tracker", help="detect, project and track the scenario's camera sequence as the RSU "
                                           "app does; position/speed/heading/class errors and false tracks "
                                           "against the simulator's truth")
    k.add_argument("--scenario", required=True, help="scenario file with a [world] camera (e.g. the IMA case study)")
    k.add_argument("--chain", default="app", choices=("app", "tracker"),
                   help="app (default): the RSU app's PerceptionStage (score threshold, detection zone, duplicate "
                        "merge, border rule, no tracks out of view) at the Settings' operating point; tracker: "
                        "every box at the detector's own threshold into a plain Kalman tracker")
    k.add_argument("--detector", default="torch", help="backend: torch or onnx (default torch, shipped weights)")
    k.add_argument("--weights", help="weights file (default the shipped ones)")
    k.add_argument("--threads", type=int, default=1,
                   help="detector CPU threads (default 1: torch's own default takes every core, which on a "
                        "2-core machine shared with other work made it about ten times slower)")
    k.add_argument("--start", type=float, help="first frame time (default the scenario's start)")
    k.add_argument("--stop", type=float, help="last frame time (default the scenario's stop)")
    k.add_argument("--rate", type=float, help="frame rate in Hz (default the camera's)")
    k.add_argument("--near", type=float, default=60.0, help="score vehicles within this range of the camera (m)")
    k.add_argument("--min-age", type=float, default=1.0, help="score tracks older than this (s)")
    op = k.add_argument_group("operating point (default the RSU app's: rsu_app.config.Settings, "
                              "scenarios/apps/rsu.toml)")
    op.add_argument("--score-threshold", help="boxes below this score are ignored (app chain only)")
    op.add_argument("--confirm-hits", help="a track is confirmed after this many detections ...")
    op.add_argument("--confirm-window", help="... within its first this many frames")
    op.add_argument("--max-missed", help="frames without a detection before a confirmed track is dropped")
    op.add_argument("--gate", help="chi-square association gate (2 dof)")
    op.add_argument("--meas-std", help="m: per-axis error of a ground position")
    op.add_argument("--motion", choices=("cv", "ctrv"),
                    help="tracker motion model: constant velocity or constant turn rate and velocity")
    k.add_argument("--json", action="store_true", help="print JSON instead of a table")
    k.set_defaults(func=_cmd_eval_tracker)


def settings_from_args(args):
    """The app's Settings with the override flags applied; ValueError naming each bad flag."""
    from rsu_app.config import ConfigError, build_settings

    given = {flag: getattr(args, dest) for flag, (dest, _) in OVERRIDES.items() if getattr(args, dest) is not None}
    problems = []
    if args.chain != "app":
        problems += [f"{flag}: applies to --chain app only (the tracker chain keeps the detector's own threshold)"
                     for flag in APP_ONLY if flag in given]
    by_key = {key: flag for flag, (_, key) in OVERRIDES.items()}
    try:
        # the evaluation signs nothing: unsecured spares it the key folder the app's signed mode requires
        flags = {"security.mode": "unsecured", **{OVERRIDES[f][1]: v for f, v in given.items()}}
        settings = build_settings(flags=flags, environ={})
    except ConfigError as exc:
        settings = None
        problems += [f"{by_key.get(key, key)}: {why}" for key, why in exc.problems]
    if problems:
        raise ValueError("\n".join(problems))
    return settings


def _cmd_eval_tracker(args) -> int:
    try:
        settings = settings_from_args(args)  # first: a bad flag is said before torch or the world loads
    except ValueError as exc:
        print("\n".join(f"error: {line}" for line in str(exc).splitlines()), file=sys.stderr)
        return 2
    from master.scenario.loader import ScenarioError
    from rsu_app.perception.detector import DetectorError, make_detector

    try:
        opts: dict = {"weights": args.weights, "threads": args.threads}
        if args.chain == "app" and args.detector != "classical":
            opts["score_threshold"] = settings.detector.score_threshold  # as the app makes its detector
        det = make_detector(args.detector, **opts)  # before the world: a missing backend is said at once
        from evaluation.tracker_sequence import evaluate_sequence

        rep = evaluate_sequence(args.scenario, det, chain=args.chain, settings=settings, start=args.start,
                                stop=args.stop, rate_hz=args.rate, near_m=args.near, min_age=args.min_age)
    except (DetectorError, ScenarioError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(rep.to_dict(), indent=2) if args.json else rep.table())
    return 0
