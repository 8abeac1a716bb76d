"""A scripted V2X station for the AV app's tests: signed surrogate BSMs at 10 Hz, through the air.

    python tests/helpers/bsm_feeder.py --keys DIR --mode true --vehicle ev --length 6.5 --rear-overhang 1.42

It is a participant of the run (it follows the master's clock like an RSU
would) and transmits on its own station `v2x/tx/<name>`; the master's air
decides delivery. Modes:

* ``true``: the emergency vehicle as it really is, from its GNSS fixes (give
  it a zero-noise `[world.vehicles.<vehicle>.gnss]` at 10 Hz): the honest
  stand-in for an RSU whose perception is perfect;
* ``ghost``: a vehicle that does not exist, on a collision course (x0, y, speed
  from flags), validly signed: the positive control for the attack runs;
* ``attacks``: the same ghost, but every frame forged (signed with a key that
  does not match the certificate it names), from an untrusted CA, altered after
  signing, or a replay of a frame captured a second earlier; plus a harmless
  parked "beacon" vehicle far away, sent validly once and replayed 50 ms later.

Keys: DIR holds `v2i-scenario-ca.cert` and `<name>.cert/.key` (PSID 0x7F), and
for ``attacks`` `other/v2i-scenario-ca.*` with `<name>.cert/.key` issued by it.
One JSON line on stdout at the end: what it sent, by kind.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections import Counter
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric import ec

from bridges.geo import GeoOrigin
from bridges.j2735.bsm import EmergencyInfo, surrogate_bsm
from bridges.security import PSID_SURROGATE_BSM, Signer, load_credentials, time64_us
from bridges.security.certificates import Credentials
from bridges.sensor_stream import GNSS_KEY, decode_fix
from bridges.timesync.participant import Participant, bus_from_env
from bridges.v2x import ENCODE, SEND, SIGN, EPOCH, stamp_ns, tx_key, unix_time

RATE_HZ = 10.0


def bsm_bytes(track: int, count: int, t: float, x: float, y: float, yaw: float, speed: float, length: float,
              width: float, origin: GeoOrigin, epoch: float, emergency: bool) -> bytes:
    lat, lon, h = origin.to_geodetic(x, y, 0.0)
    unix = unix_time(t, epoch)
    sec_mark = int(round((unix % 60.0) * 1000)) % 60000
    bsm = surrogate_bsm(track, b"feeder-salt", msg_count=count % 128, sec_mark_ms=sec_mark, latitude=float(lat),
                        longitude=float(lon), elevation=float(h), speed=max(0.0, speed),
                        heading=(90.0 - math.degrees(yaw)) % 360.0, width=width, length=length,
                        semi_major=0.2, semi_minor=0.2, orientation=0.0, transmission="forwardGears",
                        emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency")
                        if emergency else None)
    return bsm.encode()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--name", default=os.environ.get("V2I_NAME", "feeder"))
    p.add_argument("--keys", required=True)
    p.add_argument("--mode", choices=("true", "ghost", "attacks"), default="true")
    p.add_argument("--vehicle", default="ev", help="the vehicle whose GNSS fixes give its true pose (mode true)")
    p.add_argument("--length", type=float, default=6.5)
    p.add_argument("--width", type=float, default=2.3)
    p.add_argument("--rear-overhang", type=float, default=1.42, help="body behind the rear axle (fix point), m")
    p.add_argument("--ghost-x0", type=float, default=-100.0, help="ghost's centre x at t = 0 (eastbound lane)")
    p.add_argument("--ghost-y", type=float, default=-1.75)
    p.add_argument("--ghost-speed", type=float, default=16.667)
    p.add_argument("--fix-wait", type=float, default=2.0, help="wall s to wait for a due fix at a tick")
    args = p.parse_args(argv)

    keys = Path(args.keys)
    own = load_credentials(keys, args.name)
    signer = Signer(own)
    forger = Signer(Credentials(own.certificate, ec.generate_private_key(ec.SECP256R1())))  # wrong key
    untrusted = Signer(load_credentials(keys / "other", args.name)) if args.mode == "attacks" else None
    bus = bus_from_env(args.name)
    fixes = bus.subscribe(GNSS_KEY.format(args.vehicle))
    part = Participant(bus, args.name, os.environ.get("V2I_ROLE", "bsm_feeder"), publishes=[tx_key(args.name)])
    sent: Counter = Counter()
    captured: list[tuple[float, bytes]] = []  # (send time, frame) replays
    code = 0
    try:
        part.join(20.0)
        origin = part.origin or GeoOrigin()
        epoch = float(part.world[EPOCH])
        latest = None
        count = 0
        next_n = 0
        for tick in part.ticks():
            t = tick.t
            w0 = time.perf_counter()
            if math.floor(t * RATE_HZ + 1e-6) < next_n:
                part.ack(tick)
                continue
            next_n = math.floor(t * RATE_HZ + 1e-6) + 1

            def send(frame: bytes, kind: str, t_gen: float, stamps=None) -> None:
                t_out = part.output_time("send", time.perf_counter() - w0, tick)
                st = {**(stamps or {}), SEND: stamp_ns(t_out)}
                bus.publish(tx_key(args.name), frame, t_out, stamps=st)
                sent[kind] += 1

            def sign(payload: bytes, t_gen: float, who: Signer = signer) -> bytes:
                return who.sign(payload, PSID_SURROGATE_BSM, time64_us(unix_time(t_gen, epoch)))

            if args.mode == "true":
                deadline = time.monotonic() + args.fix_wait
                while True:  # the fix of time t is published before the tick: wait for it, bounded
                    msg = fixes.recv(timeout=0.0)
                    if msg is not None:
                        latest = decode_fix(msg.payload)
                        continue
                    if latest is not None and latest.t >= t - 1e-9 or time.monotonic() > deadline:
                        break
                    time.sleep(0.001)
                if latest is not None and abs(latest.t - t) < 1e-6:
                    off = args.length / 2 - args.rear_overhang
                    cx = latest.x + off * math.cos(latest.heading)
                    cy = latest.y + off * math.sin(latest.heading)
                    payload = bsm_bytes(1, count, t, cx, cy, latest.heading, latest.speed, args.length,
                                        args.width, origin, epoch, True)
                    count += 1
                    send(sign(payload, t), "true", t, {ENCODE: stamp_ns(t), SIGN: stamp_ns(t)})
                else:
                    sent["no_fix"] += 1
            else:
                gx = args.ghost_x0 + args.ghost_speed * t
                ghost = bsm_bytes(7, count, t, gx, args.ghost_y, 0.0, args.ghost_speed, args.length, args.width,
                                  origin, epoch, True)
                count += 1
                if args.mode == "ghost":
                    send(sign(ghost, t), "ghost", t)
                else:
                    send(forger.sign(ghost, PSID_SURROGATE_BSM, time64_us(unix_time(t, epoch))), "forged", t)
                    send(sign(ghost, t, untrusted), "untrusted", t)
                    good = bytearray(sign(ghost, t))
                    at = good.find(ghost)
                    good[at + len(ghost) // 2] ^= 0x01  # a bit flipped in transit, after signing
                    send(bytes(good), "altered", t)
                    # a frame of the ghost captured now, replayed one second later (stale by then)
                    captured.append((t + 1.0, sign(ghost, t)))
                    while captured and captured[0][0] <= t + 1e-9:
                        send(captured.pop(0)[1], "replayed_stale", t)
                    beacon = sign(bsm_bytes(9, count, t, -1.75, 100.0, -math.pi / 2, 0.0, 4.5, 1.8, origin, epoch,
                                            False), t)
                    send(beacon, "beacon", t)
                    captured_dup = beacon
                    send(captured_dup, "replayed_duplicate", t)  # the same signed bytes again
            part.ack(tick, time.perf_counter() - w0)
    except Exception as exc:  # report, exit non-zero: the run names us as lost
        print(f"{args.name}: {type(exc).__name__}: {exc}", file=sys.stderr)
        code = 1
    finally:
        part.close()
        fixes.close()
        bus.close()
        print(json.dumps({"name": args.name, "mode": args.mode, "sent": dict(sent)}), flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
