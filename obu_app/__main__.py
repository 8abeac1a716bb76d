"""`python -m obu_app --config FILE`: the emergency vehicle's OBU (signal preemption requests) in a run.

Exit codes: 0 the run ended (or SIGTERM), 1 internal error, 2 bad configuration
(every problem named by key), 3 refused by the master, 4 no master answered,
5 the master went silent. One JSON summary line on stdout at exit.
"""
from __future__ import annotations

import argparse
import logging
import sys

from bridges.timesync.exits import EXIT_CONFIG
from obu_app.config import ConfigError, ObuConfig, read


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m obu_app", description=__doc__.split("\n\n")[0])
    p.add_argument("--config", metavar="FILE", help="TOML file: [app], [bus], [security], [evsp]")
    p.add_argument("--no-request", action="store_true", help="listen only: send no SRM ([evsp] enabled = false)")
    p.add_argument("--log-level", default="WARNING")
    args = p.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="obu_app %(levelname)s %(message)s")
    try:
        cfg = read(args.config) if args.config else ObuConfig()
        if args.no_request:
            cfg.evsp.enabled = False
        from obu_app.app import ObuApp

        app = ObuApp(cfg)
    except ConfigError as exc:
        for problem in exc.problems:
            print(f"obu_app: {problem}", file=sys.stderr)
        return EXIT_CONFIG
    return app.run()


if __name__ == "__main__":
    sys.exit(main())
