"""`python -m attacker`: a V2X attacker as a participant of the run (ghost vehicles, replays, a flood).

    python -m attacker --config scenarios/apps/attacker.toml         # started by `v2i run` (bus from V2I_*)
    python -m attacker --attack "ghost-unsigned: start_s = 1.0" --attack "flood: rate_hz = 500, max_frames = 300"
    python -m attacker --list                                        # every attack and its parameters

Exit codes: 0 the run ended (or SIGTERM), 1 internal error, 2 bad configuration
(every problem named by key), 3 refused by the master, 4 no master answered,
5 the master went silent. One JSON summary line on stdout at exit: frames sent
per attack.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys

from attacker.attacks import describe
from attacker.config import ConfigError, build, parse_attack_flag, read_toml

# flag dest -> (table, key); paths are made absolute (relative to the working directory)
_FLAGS = {"name": ("app", "name"), "station": ("app", "station"), "seed": ("app", "seed"),
          "frame_log": ("app", "frame_log"), "join_timeout": ("app", "join_timeout_s"),
          "bus": ("bus", "transport"), "prefix": ("bus", "prefix"), "connect": ("bus", "connect"),
          "pki_dir": ("keys", "pki_dir"), "stolen_dir": ("keys", "stolen_dir")}
_PATHS = ("frame_log", "pki_dir", "stolen_dir")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m attacker", description=__doc__.split("\n\n")[0].split(": ", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1] + "\nAttacks and their parameters:\n" + describe())
    p.add_argument("--config", metavar="FILE", help="TOML config file ([app], [bus], [keys], [[attacks]])")
    p.add_argument("--attack", action="append", default=[], metavar="KIND[: key = value, ...]",
                   help="add an attack (repeatable), e.g. \"replay: delay_s = 1.0\"")
    p.add_argument("--list", action="store_true", help="print the attacks and their parameters and exit")
    p.add_argument("--print-config", action="store_true", help="print the resolved configuration as JSON and exit")
    p.add_argument("--name", help="participant name [app.name] (default $V2I_NAME, else attacker)")
    p.add_argument("--station", help="its V2X station [app.station] (default: the name)")
    p.add_argument("--seed", type=int, help="[app.seed]: ghost ids and flood bytes")
    p.add_argument("--frame-log", metavar="FILE", help="[app.frame_log]: one JSON line per frame sent")
    p.add_argument("--join-timeout", type=float, help="[app.join_timeout_s]")
    p.add_argument("--bus", help="transport: zenoh, udp, memory [bus.transport] (default $V2I_BUS)")
    p.add_argument("--prefix", help="run prefix [bus.prefix] (default $V2I_PREFIX)")
    p.add_argument("--connect", help="endpoints, comma-separated [bus.connect] (default $V2I_CONNECT)")
    p.add_argument("--pki-dir", help="[keys.pki_dir]: the scenario CA (to issue the stolen certificate if missing)")
    p.add_argument("--stolen-dir", help="[keys.stolen_dir]: the stolen, expired certificate and key")
    return p


def config_from_args(args, environ=os.environ):
    tables = read_toml(args.config) if args.config else {}
    for dest, (table, key) in _FLAGS.items():
        value = getattr(args, dest)
        if value is None:
            continue
        if dest in _PATHS:
            value = os.path.abspath(value)
        tables.setdefault(table, {})
        if not isinstance(tables[table], dict):
            raise ConfigError([(table, f"expected a table, got {tables[table]!r}")])
        tables[table][key] = value
    if args.attack:
        attacks = tables.setdefault("attacks", [])
        if not isinstance(attacks, list):
            raise ConfigError([("attacks", "expected [[attacks]] tables")])
        attacks.extend(parse_attack_flag(text) for text in args.attack)
    return build(tables, environ)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.list:
        print(describe())
        return 0
    logging.basicConfig(level=logging.INFO, format="attacker: %(levelname)s %(name)s: %(message)s")
    try:
        cfg = config_from_args(args)
        if args.print_config:
            print(json.dumps(cfg.to_dict(), indent=2, default=str))
            return 0
        from attacker.app import AttackerApp

        app = AttackerApp(cfg)
    except ConfigError as exc:
        for key, why in exc.problems:
            print(f"attacker: config: {key}: {why}", file=sys.stderr)
        return 2
    return app.run()


if __name__ == "__main__":
    sys.exit(main())
