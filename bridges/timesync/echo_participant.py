"""A demo participant: joins, acknowledges every tick; misbehaves on request (for tests).

    python -m bridges.timesync.echo_participant [--name echo] [--delay 0.001]
           [--stall-after N] [--crash-after N] [--version 2.0] [--clock-offset 0.25]

The bus comes from the environment the master sets for participants it starts
(V2I_BUS, V2I_PREFIX, V2I_CONNECT, V2I_BUS_OPTIONS, V2I_NAME, V2I_ROLE), or from
--bus/--prefix/--connect. One JSON line on stdout at the end says what it did.
Exit codes: 0 run ended normally, 3 refused, 4 no welcome, 5 master lost, 17 --crash-after.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time

from bridges.timesync.errors import JoinTimeout, MasterLost, Refused
from bridges.timesync.participant import Participant, bus_from_env


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="echo_participant", description=__doc__.split("\n")[0])
    p.add_argument("--name", default=os.environ.get("V2I_NAME", "echo"))
    p.add_argument("--role", default=os.environ.get("V2I_ROLE", "echo"))
    p.add_argument("--bus", help="transport (default: $V2I_BUS)")
    p.add_argument("--prefix", help="key prefix (default: $V2I_PREFIX)")
    p.add_argument("--connect", help="endpoints, comma-separated (default: $V2I_CONNECT)")
    p.add_argument("--delay", type=float, default=0.0, help="wall seconds of 'work' per tick")
    p.add_argument("--stall-after", type=int, help="stop acknowledging after N ticks (keeps heartbeating)")
    p.add_argument("--crash-after", type=int, help="exit abruptly (code 17, no leave) after N ticks")
    p.add_argument("--leave-after", type=int, help="leave the run politely after N ticks")
    p.add_argument("--version", default=None, help="announce this protocol version, e.g. 2.0 (tests)")
    p.add_argument("--clock-offset", type=float, default=0.0, help="add this many seconds to the local clock")
    p.add_argument("--join-timeout", type=float, default=20.0)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format=f"{args.name}: %(levelname)s %(message)s")

    bus = bus_from_env(args.name, transport=args.bus, prefix=args.prefix, connect=args.connect)
    offset_ns = round(args.clock_offset * 1e9)
    options = {"clock_ns": (lambda: time.time_ns() + offset_ns)} if offset_ns else {}
    if args.version:
        options["version"] = [int(x) for x in args.version.split(".")][:2] + [0] * (2 - len(args.version.split(".")))
    part = Participant(bus, args.name, args.role, publishes=[], **options)
    done, code, result = 0, 0, {"name": args.name}
    try:
        welcome = part.join(timeout=args.join_timeout)
        result["mode"] = welcome.mode
        for tick in part.ticks():
            t0 = time.perf_counter()
            if args.delay:
                time.sleep(args.delay)
            if args.crash_after is not None and done >= args.crash_after:
                os._exit(17)
            if args.stall_after is not None and done >= args.stall_after:
                time.sleep(3600)
            if args.leave_after is not None and done >= args.leave_after:
                part.leave(f"--leave-after {args.leave_after}")
                break
            part.ack(tick, time.perf_counter() - t0)
            done += 1
        result["end"] = part.ended.status if part.ended else None
    except Refused as exc:
        print(exc, file=sys.stderr)
        result["refused"], code = exc.reason, 3
    except JoinTimeout as exc:
        print(exc, file=sys.stderr)
        code = 4
    except MasterLost as exc:
        print(exc, file=sys.stderr)
        code = 5
    finally:
        result.update(ticks=done, errors=dict(part.errors))
        if part.offset:
            result.update(offset_ns=part.offset.offset_ns, rtt_ns=part.offset.rtt_ns)
        part.close()
        bus.close()
    print(json.dumps(result), flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
