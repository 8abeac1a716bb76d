"""`v2i pki init DIR --station NAME:PSID[,PSID…]`: a scenario CA and station credentials as files."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bridges.security.certificates import ScenarioCA


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("pki", help="create a scenario CA and station certificates (1609.2-style)")
    psub = p.add_subparsers(dest="pki_command", required=True)
    init = psub.add_parser("init", help="write <name>.cert/<name>.key for a CA and its stations")
    init.add_argument("dir")
    init.add_argument("--station", action="append", default=[], metavar="NAME:PSID[,PSID...]",
                      help="a station and the PSIDs it may sign, e.g. rsu1:0x7f,0x82 (repeatable)")
    init.add_argument("--hours", type=int, default=24 * 30, help="station certificate lifetime (default 720)")
    init.set_defaults(func=_cmd_init)


def parse_station(text: str) -> tuple[str, list[int]]:
    name, sep, psids = text.partition(":")
    if not name or not sep or not psids:
        raise ValueError(f"--station {text!r}: expected NAME:PSID[,PSID...]")
    try:
        return name, [int(p, 0) for p in psids.split(",")]
    except ValueError:
        raise ValueError(f"--station {text!r}: PSIDs must be integers (0x7f or 127)") from None


def _cmd_init(args) -> int:
    try:
        stations = [parse_station(s) for s in args.station]
    except ValueError as exc:
        print(f"v2i pki init: {exc}", file=sys.stderr)
        return 2
    directory = Path(args.dir)
    if (directory / "v2i-scenario-ca.key").exists():
        print(f"v2i pki init: {directory} already holds a CA; refusing to overwrite it", file=sys.stderr)
        return 1
    ca = ScenarioCA.create()
    ca.credentials.save(directory)
    for name, psids in stations:
        ca.issue(name, psids, hours=args.hours).save(directory)
        print(f"{name}: PSIDs {', '.join(hex(p) for p in psids)}")
    print(f"CA and {len(stations)} station(s) written to {directory}")
    return 0
