"""`v2i dataset`: labelled camera frames from a scenario's world.

Beside the scenario reader, not in `master/world/`: it loads a scenario, and
`master.scenario.loader` imports `master.world.layout`, so a world module reading
scenarios would close an import cycle (tests/test_boundaries.py).
"""
from __future__ import annotations

import sys
from pathlib import Path


def _cmd_dataset(args) -> int:
    from master.scenario.loader import load_scenario_or_report
    from master.world.dataset import DatasetError, make_dataset

    sc = load_scenario_or_report(args.scenario)
    if sc is None:
        return 2
    if sc.world is None:
        print(f"error: {args.scenario}: no [world] table to render a dataset from", file=sys.stderr)
        return 2
    try:
        coco = make_dataset(sc.world, Path(args.out), args.frames, args.seed, args.variant, args.camera,
                            args.jobs, occlusion=not args.no_occlusion, force=args.force,
                            scenario=str(args.scenario), progress=not args.quiet, backgrounds=args.backgrounds)
    except DatasetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    n = len(coco["annotations"])
    ignored = sum(a["ignore"] for a in coco["annotations"])
    print(f"{args.out}: {len(coco['images'])} frames, {n} vehicle labels ({ignored} marked ignore), "
          f"variant {args.variant}, seed {args.seed}")
    return 0


def add_parser(sub) -> None:
    d = sub.add_parser("dataset", help="render labelled camera frames (COCO-style JSON + PNG) for detectors")
    d.add_argument("--scenario", required=True, help="scenario file with a [world] table")
    d.add_argument("--out", required=True, help="output folder (must be empty unless --force)")
    d.add_argument("--frames", type=int, default=100, help="number of frames (default 100)")
    d.add_argument("--seed", type=int, default=0, help="random seed; the same seed gives the same dataset")
    d.add_argument("--variant", choices=("train", "heldout", "wide"), default="train",
                   help="heldout draws colours, sizes and camera poses that train never uses; wide (the shipped "
                        "detector's training set) brackets heldout's ranges on every side without touching them")
    d.add_argument("--camera", help="scenario camera whose pose is jittered (default: the first)")
    d.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    d.add_argument("--no-occlusion", action="store_true",
                   help="skip the exact occlusion fractions (one extra render per vehicle in view)")
    d.add_argument("--backgrounds", action="store_true",
                   help="also write each frame's view without vehicles (for background-subtraction baselines)")
    d.add_argument("--force", action="store_true", help="write into a non-empty folder")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_cmd_dataset)
