"""The `v2i` command line.

Exit codes: 0 success, 1 the run failed (FMU error, deadline miss,
interrupted), 2 bad input (scenario, FMU file, arguments).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path



def _cmd_build_fmus(args) -> int:
    from fmus.builder import BuildError, build_all

    try:
        results = build_all(Path(args.out), force=args.force, only=args.names or None)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for r in results:
        print(f"{'built  ' if r.built else 'up to date'} {r.name:24s} {r.path}")
    return 0


def _cmd_validate(args) -> int:
    from master.scenario import load_scenario_or_report

    worst = 0
    for path in args.files:
        sc = load_scenario_or_report(path)
        if sc is None:
            worst = 2
            continue
        print(f"{path}: ok ({len(sc.instances)} instances, {len(sc.connections)} connections, "
              f"{sc.time.n_steps} steps of {sc.time.step} s, {sc.time.mode}, {sc.time.ordering})")
    return worst


def _cmd_run(args) -> int:
    from master.cosim import CoSimulation
    from master.scenario import load_scenario_or_report
    from master.summary import format_summary

    sc = load_scenario_or_report(args.file)
    if sc is None:
        return 2
    overrides = {k: v for k, v in (("mode", args.mode), ("ordering", args.ordering),
                                   ("rtf", args.rtf), ("overrun", args.overrun)) if v is not None}
    if args.rtf is not None and args.rtf <= 0:
        print(f"error: --rtf must be > 0, got {args.rtf}", file=sys.stderr)
        return 2
    sc.time = replace(sc.time, **overrides)
    try:
        result = CoSimulation(sc, Path(args.out) if args.out else None, quiet=args.quiet).run()
    except FileExistsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_summary(result))
    if result.status != "completed":
        print(f"error: {result.error}", file=sys.stderr)
        return 1
    return 0


def _cmd_info(args) -> int:
    from master.fmu_info import describe

    try:
        print(describe(args.fmu))
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    from master import __version__

    p = argparse.ArgumentParser(prog="v2i", description="V2I co-simulation: FMUs, scenarios, runs.")
    p.add_argument("--version", action="version", version=f"v2i-cosim {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build-fmus", help="build the project's FMUs (skips unchanged ones)")
    b.add_argument("names", nargs="*", help="model identifiers to build (default: all)")
    b.add_argument("--out", default="build/fmus", help="output folder (default: build/fmus)")
    b.add_argument("--force", action="store_true", help="rebuild even if sources are unchanged")
    b.set_defaults(func=_cmd_build_fmus)

    v = sub.add_parser("validate", help="check scenario files without running them")
    v.add_argument("files", nargs="+")
    v.set_defaults(func=_cmd_validate)

    r = sub.add_parser("run", help="run a scenario into a run folder")
    r.add_argument("file")
    r.add_argument("--out", help="run folder (default: runs/<scenario>-<timestamp>); never overwritten")
    r.add_argument("--mode", choices=("lockstep", "realtime"), help="override time.mode")
    r.add_argument("--ordering", choices=("jacobi", "gauss-seidel"), help="override time.ordering")
    r.add_argument("--rtf", type=float, help="realtime: target real-time factor (override time.rtf)")
    r.add_argument("--overrun", choices=("catch-up", "skip", "slip", "abort"), help="realtime overrun policy")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=_cmd_run)

    i = sub.add_parser("info", help="list an FMU's variables")
    i.add_argument("fmu", help="an .fmu file or a project FMU name")
    i.set_defaults(func=_cmd_info)

    from bridges.j2735 import cli as j2735_cli
    from bridges.security import cli as pki_cli

    from master import dataset_cli, snapshot
    from rsu_app.perception import cli as perception_cli  # the RSU's detector tools share the `v2i` command

    j2735_cli.add_parser(sub)
    pki_cli.add_parser(sub)
    snapshot.add_parser(sub)
    dataset_cli.add_parser(sub)
    perception_cli.add_parser(sub)  # train-detector, eval-detector, eval-tracker, export-detector
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


def entry() -> None:
    """The `v2i` console script: main(), then leave without running native libraries' exit code.

    Some native teardown (zenoh's runtime threads, Mesa EGL, the FMUs' shared
    objects unloaded by dlclose) was seen to abort with a corrupted heap after a
    run had finished and written everything; the run's outcome is the exit
    status, so nothing is lost by skipping that teardown.
    """
    import logging
    import os

    code = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
