"""`python -m rsu_app` / `v2i-rsu`: the RSU application (seed paper stages 1 and 2, plus SPaT and MAP).

    python -m rsu_app --config scenarios/apps/rsu.toml           # started by `v2i run` (bus from V2I_*)
    v2i-rsu --bus zenoh --prefix v2i/lab1 --connect tcp/MASTER:7447 --pki-dir keys/ --name rsu   # on a box

Exit codes: 0 the run ended (or SIGTERM), 1 internal error, 2 bad configuration
(every problem named by key), 3 refused by the master, 4 no master answered,
5 the master went silent. One JSON summary line on stdout at exit; a stats line
on stderr every `health.stats_every_s`.
"""
from __future__ import annotations

import os

# Before numpy and the detector runtimes load: their implicit thread pools must not oversubscribe a machine
# shared with the master (the detector's own threads are set explicitly from detector.threads).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402

from rsu_app.config import SCHEMA, ConfigError, build_settings, help_text, read_toml  # noqa: E402


PATH_KEYS = (("security", "pki_dir"), ("detector", "weights"), ("detector", "background"))


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="v2i-rsu", description=__doc__.split("\n\n")[0].split(": ", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 1)[1] + "\n" + help_text())
    p.add_argument("--config", metavar="FILE", help="TOML config file (keys below)")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="set any config key (repeatable), e.g. --set tracker.max_missed=8")
    p.add_argument("--print-config", action="store_true", help="print the resolved configuration as JSON and exit")
    for spec in SCHEMA:
        if spec.flag:
            metavar = "A,B" if spec.type.startswith("list[") else spec.type.upper()
            kwargs = {"dest": "key:" + spec.dotted, "metavar": metavar, "help": f"{spec.help} ({spec.dotted})"}
            if spec.type.startswith("list["):
                kwargs["action"] = "append"
            p.add_argument(spec.flag, **kwargs)
    return p


def settings_from_args(args, environ=os.environ):
    flags = {}
    problems = []
    for dest, value in vars(args).items():
        if dest.startswith("key:") and value is not None:
            flags[dest[4:]] = ",".join(value) if isinstance(value, list) else value
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            problems.append(("--set", f"expected SECTION.KEY=VALUE, got {item!r}"))
            continue
        flags.setdefault(key.strip(), value.strip())
    config = {}
    if args.config:
        config = read_toml(args.config)
        base = os.path.dirname(os.path.abspath(args.config))
        for section, key in PATH_KEYS:  # paths in a config file are relative to the file
            table = config.get(section)
            if isinstance(table, dict) and isinstance(table.get(key), str) and not os.path.isabs(table[key]):
                table[key] = os.path.join(base, table[key])
    if problems:
        raise ConfigError(problems)
    return build_settings(flags, config, environ)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        settings = settings_from_args(args)
    except ConfigError as exc:
        for key, why in exc.problems:
            print(f"rsu_app: config: {key}: {why}", file=sys.stderr)
        return 2
    logging.basicConfig(level=getattr(logging, settings.health.log_level.upper()),
                        format=f"{settings.name or 'rsu'}: %(levelname)s %(name)s: %(message)s")
    if args.print_config:
        import json

        print(json.dumps(settings.to_dict(), indent=2))
        return 0
    from rsu_app.app import RsuApp

    try:
        app = RsuApp(settings)
    except ConfigError as exc:
        for key, why in exc.problems:
            print(f"rsu_app: config: {key}: {why}", file=sys.stderr)
        return 2
    return app.run()


def entry() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entry()
