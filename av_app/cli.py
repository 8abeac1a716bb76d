"""`python -m av_app` / `v2i-av`: the connected automated vehicle's software as a process.

Receives V2X frames for its station, verifies and decodes them, fuses them
with its own lidar obstacles, estimates conflicts, plans a speed profile,
follows its route, and drives the vehicle over CAN (AV_Command answering each
AV_Status), following the master's clock. Settings come from flags, a TOML
config (--config), and the bus variables the master sets (V2I_BUS, V2I_PREFIX,
V2I_CONNECT, V2I_BUS_OPTIONS, V2I_NAME, V2I_ROLE), in that order of precedence.

Exit codes: 0 the run ended; 1 internal error; 2 bad configuration (every
problem named by key); 3 refused by the master; 4 no master answered; 5 the
master went silent. A stats line goes to stderr every few seconds, a JSON
summary to stdout at exit.
"""
from __future__ import annotations

import argparse
import json
import logging
import re
import sys
import tomllib
from pathlib import Path

from av_app.config import ConfigError, describe, load

# flag -> (table, key, type)
_FLAGS = {
    "name": ("app", "name", str), "role": ("app", "role", str), "station": ("app", "station", str),
    "vehicle": ("app", "vehicle", str), "stats_every": ("app", "stats_every_s", float),
    "join_timeout": ("app", "join_timeout_s", float), "plan_log": ("app", "plan_log", str),
    "bus": ("bus", "transport", str), "prefix": ("bus", "prefix", str), "connect": ("bus", "connect", str),
    "trust_anchor": ("security", "trust_anchor", str),
    "can_interface": ("can", "interface", str), "can_channel": ("can", "channel", str),
    "can_port": ("can", "port", int), "can_iface": ("can", "iface", str),
    "no_lidar": ("perception", "enabled", bool),
}


_PATHS = ("trust_anchor", "plan_log")  # flags that name files: relative to the working directory, not the config


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="v2i-av", description="The connected automated vehicle's software (stage 3 of the IMA case study): "
                                   "V2X receive, lidar perception, fusion, conflict estimation, planning, CAN.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="\n\n".join(__doc__.split("\n\n")[1:]) + "\n\nConfig file tables and keys (defaults):\n" + describe())
    p.add_argument("--config", help="TOML config file (tables and keys below)")
    p.add_argument("--name", help="participant name [app.name] (default $V2I_NAME, else cav)")
    p.add_argument("--role", help="role announced to the master [app.role] (default $V2I_ROLE, else av_app)")
    p.add_argument("--station", help="V2X station to receive for [app.station] (default: the name)")
    p.add_argument("--vehicle", help="world vehicle whose lidar/gnss streams to use [app.vehicle] (default: the name)")
    p.add_argument("--bus", help="transport: zenoh, udp, memory [bus.transport] (default $V2I_BUS)")
    p.add_argument("--prefix", help="run prefix [bus.prefix] (default $V2I_PREFIX)")
    p.add_argument("--connect", help="endpoints, comma-separated [bus.connect] (default $V2I_CONNECT)")
    p.add_argument("--trust-anchor", help="scenario CA certificate [security.trust_anchor]")
    p.add_argument("--can-interface", help="python-can interface [can.interface]")
    p.add_argument("--can-channel", help="CAN channel / multicast group [can.channel]")
    p.add_argument("--can-port", type=int, help="udp_multicast port [can.port]; must match the scenario's [can]")
    p.add_argument("--can-iface", help="udp_multicast interface address [can.iface]")
    p.add_argument("--no-lidar", action="store_true", default=None, help="do not run the lidar pipeline")
    p.add_argument("--stats-every", type=float, help="wall seconds between stats lines [app.stats_every_s]")
    p.add_argument("--join-timeout", type=float, help="wall seconds to wait for the master [app.join_timeout_s]")
    p.add_argument("--plan-log", help="write one JSON line per plan to this file [app.plan_log]")
    p.add_argument("--set", action="append", default=[], metavar="TABLE.KEY=VALUE",
                   help="set any config key (repeatable), e.g. --set route.cruise_speed=5.556; VALUE is a TOML "
                        "literal, or a bare word taken as a string (the named flags above win over it)")
    p.add_argument("--print-config", action="store_true", help="print the resolved configuration as JSON and exit")
    p.add_argument("--log-level", default="WARNING", help="DEBUG, INFO, WARNING (default), ERROR")
    return p


def overrides(args: argparse.Namespace) -> dict[str, dict]:
    """The config tables the flags set: --set TABLE.KEY=VALUE first, the named flags over them.
    ConfigError naming each malformed --set."""
    out: dict[str, dict] = {}
    problems = []
    for item in getattr(args, "set", None) or []:
        key, sep, text = item.partition("=")
        table, dot, name = key.strip().partition(".")
        value = _set_value(text.strip())
        if not sep or not dot or not table or not name or value is None:
            problems.append(f"--set {item}: expected TABLE.KEY=VALUE with a TOML value or a bare word")
            continue
        out.setdefault(table, {})[name] = value
    if problems:
        raise ConfigError(problems, "--set")
    for flag, (table, key, kind) in _FLAGS.items():
        value = getattr(args, flag, None)
        if value is None:
            continue
        if flag == "connect":
            value = [c.strip() for c in value.split(",") if c.strip()]
        elif flag in _PATHS and value:
            value = str(Path(value).expanduser().resolve())  # a path on the command line is from here
        elif flag == "no_lidar":
            value = not value
        out.setdefault(table, {})[key] = value
    return out


def _set_value(text: str):
    """A TOML literal (5.5, true, "a b", [1, 2]), or a bare word as that string; None when neither."""
    try:
        doc = tomllib.loads(f"v = {text}")
        if list(doc) == ["v"]:
            return doc["v"]
    except tomllib.TOMLDecodeError:
        pass
    return text if re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.:/@+\-]*", text) else None


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    level = getattr(logging, str(args.log_level).upper(), None)
    if not isinstance(level, int):
        print(f"--log-level: {args.log_level!r} is not a level (DEBUG, INFO, WARNING, ERROR)", file=sys.stderr)
        return 2
    try:
        cfg = load(args.config, overrides(args))
    except ConfigError as exc:
        for problem in exc.problems:
            print(f"{exc.source}: {problem}", file=sys.stderr)
        return 2
    logging.basicConfig(level=level, format=f"{cfg.app.name}: %(levelname)s %(message)s")
    if args.print_config:
        print(json.dumps(cfg.to_dict(), indent=2, default=str))
        return 0
    from av_app.app import run_app

    return run_app(cfg)


if __name__ == "__main__":
    sys.exit(main())
