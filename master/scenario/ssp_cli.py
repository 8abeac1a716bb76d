"""`v2i export-ssp SCENARIO.toml -o system.ssp`: the scenario's FMU system as an SSP 1.0 package (master.scenario.ssp_export).

The way back needs no command of its own: `v2i run system.ssp` and `v2i validate system.ssp` read a
package like a scenario file (master.scenario.ssp_import). Exit codes as the rest of `v2i`: 0 written (what was
left out is printed as a warning), 2 a bad scenario or a scenario that has no SSP form.
"""
from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser("export-ssp", help="write a scenario's FMUs, connections, parameters and experiment as an "
                                          "SSP 1.0 package for other FMI tools")
    e.add_argument("file", help="a scenario file (.toml)")
    e.add_argument("-o", "--out", required=True, help="the package to write (e.g. system.ssp); replaced if it exists")
    e.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a value of the scenario before exporting (as `v2i run --set`; repeatable)")
    e.set_defaults(func=_cmd_export_ssp)


def _cmd_export_ssp(args) -> int:
    from master.scenario.loader import load_scenario_or_report
    from master.scenario.ssp import SspError
    from master.scenario.ssp_export import export_ssp

    sc = load_scenario_or_report(args.file, args.set)
    if sc is None:
        return 2
    try:
        warnings = export_ssp(sc, args.out)
    except (SspError, OSError) as exc:
        print(f"v2i export-ssp: {exc}", file=sys.stderr)
        return 2
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    print(f"{args.out}: SSP 1.0, {len(sc.instances)} components, {len(sc.connections)} connections, "
          f"{sc.time.start:g}..{sc.time.stop:g} s in steps of {sc.time.step:g} s")
    return 0
