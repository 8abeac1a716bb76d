"""`v2i report RUN_DIR [RUN_DIR2] [--out PAGE]`: the run's HTML page (master.report.page), from the command line.

Exit codes as the rest of `v2i`: 0 page written, 2 a folder that is not a run folder.
"""
from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("report", help="one self-contained HTML page of a run (or two side by side): verdict, "
                                      "trajectories, speeds, gaps, latencies, the camera clip")
    r.add_argument("runs", nargs="+", metavar="RUN_DIR", help="one run folder, or two to compare (e.g. with and "
                                                              "without the RSU's perception service)")
    r.add_argument("--out", help="page to write (default: RUN_DIR/report.html, or RUN_DIR/report-vs-<RUN_DIR2>.html)")
    r.set_defaults(func=_cmd_report)


def _cmd_report(args) -> int:
    from master.report.page import ReportError, write_report

    if len(args.runs) > 2:
        print(f"v2i report: give one or two run folders, got {len(args.runs)}", file=sys.stderr)
        return 2
    try:
        page, clips = write_report(args.runs, args.out)
    except ReportError as exc:
        print(f"v2i report: {exc}", file=sys.stderr)
        return 2
    for run, clip in zip(args.runs, clips):
        if clip:
            print(f"{run}: clip {clip['frames']} frames {clip['width']}x{clip['height']}")
    print(f"report: {page}")
    return 0
