"""Hello, V2X: the guide's minimal app (docs/writing-an-app.md), a participant built on `bridges` alone.

It rides one vehicle of the run: once a second it broadcasts a signed BSM of its vehicle (from the master's GNSS
fixes), and it verifies, decodes and traces every frame it hears on the V2X air. `v2i run examples/hello.toml`
starts two of them, one per vehicle, so frames go both ways. At the end: one JSON summary line on stdout.

    python -m examples.hello_app --name cav --vehicle cav --keys keys      (the master sets the bus variables)
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import zlib
from collections import Counter

from bridges.app_session import AppSession
from bridges.j2735 import J2735Error, default_codec
from bridges.j2735.bsm import Bsm
from bridges.security import PSID_BSM, SecurityError, Signer, VerificationError, load_credentials, time64_us
from bridges.security.trust import load_trust_store
from bridges.sensor_stream import GNSS_KEY, SensorStreamError, decode_fix
from bridges.timesync.exits import EXIT_CONFIG, EXIT_OK, SESSION_ERRORS, session_end
from bridges.v2x import RECEIVE, SEND, rx_key, stamp_ns, tx_key, unix_time


def bsm_of(fix, count: int, name: str, unix_s: float, origin) -> Bsm:
    """The vehicle's own BSM from a GNSS fix (local metres -> WGS-84, yaw CCW from east -> heading from north)."""
    lat, lon, _ = origin.to_geodetic(fix.x, fix.y)
    return Bsm(temporary_id=zlib.crc32(name.encode()).to_bytes(4, "big"), msg_count=count % 128,
               sec_mark_ms=round(unix_s * 1000) % 60000, latitude=lat, longitude=lon, speed=fix.speed,
               heading=(90.0 - math.degrees(fix.heading)) % 360.0, length=4.5, width=1.8)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m examples.hello_app", description=__doc__.split("\n")[0])
    p.add_argument("--name", required=True, help="participant name, also its V2X station and certificate")
    p.add_argument("--vehicle", required=True, help="the vehicle it rides (its GNSS fixes)")
    p.add_argument("--keys", default="keys", help="the scenario's PKI folder (v2i pki init)")
    p.add_argument("--rate-hz", type=float, default=1.0, help="BSMs per second")
    a = p.parse_args(argv)
    if not a.rate_hz > 0:
        p.error(f"--rate-hz must be > 0, got {a.rate_hz}")
    try:  # the keys first (a bad folder is a config error) and the codec (built once, seconds) before joining
        signer, verifier = Signer(load_credentials(a.keys, a.name)), load_trust_store(a.keys).verifier()
        default_codec()
    except SecurityError as exc:
        print(f"hello: keys: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    s = AppSession(a.name, "hello_app", listen=[rx_key(a.name), GNSS_KEY.format(a.vehicle)],
                   publishes=[tx_key(a.name)])
    code, fix, sent, bad_gnss, heard, rejected, due = EXIT_OK, None, 0, 0, Counter(), Counter(), 0.0
    try:
        s.open()
        for step in s.steps():
            for msg in step.heard:
                try:  # a GNSS fix of its vehicle, or a frame off the air: verified at its arrival time, decoded
                    if msg.key.startswith("gnss/"):
                        fix = decode_fix(msg.payload)
                        continue
                    v = verifier.verify(msg.payload, time64_us(unix_time(msg.t_sim, s.epoch)))
                    bsm = Bsm.decode(v.payload) if v.psid == PSID_BSM else None  # J2735Error: not a BSM
                    if bsm is None or bsm.latitude is None:
                        raise J2735Error("psid-mismatch" if bsm is None else "no-position")
                except VerificationError as exc:  # bad-signature, replayed, untrusted-signer, ...: counted
                    rejected[exc.reason.value] += 1
                    continue
                except J2735Error as exc:
                    rejected[exc.reason if exc.reason in ("psid-mismatch", "no-position") else "undecodable"] += 1
                    continue
                except SensorStreamError:
                    bad_gnss += 1
                    continue
                heard[v.signer] += 1
                x, y, _ = s.origin.to_local(bsm.latitude, bsm.longitude)
                s.trace({"app": "hello", "from": v.signer, "x": round(x, 2), "y": round(y, 2), "speed": bsm.speed},
                        step.t, stamps={**msg.stamps, RECEIVE: stamp_ns(step.t)})
            if fix is not None and step.t >= due - 1e-9:  # the rate's grid: the same instants in every run
                t = s.output_time("send")
                bsm = bsm_of(fix, sent, a.name, unix_time(t, s.epoch), s.origin)
                frame = signer.sign(bsm.encode(), PSID_BSM, time64_us(unix_time(t, s.epoch)))
                s.publish(tx_key(a.name), frame, t, stamps={SEND: stamp_ns(t)})
                sent, due = sent + 1, due + 1.0 / a.rate_hz
    except SESSION_ERRORS as exc:
        code = session_end(exc)[0]
        print(f"hello: {exc}", file=sys.stderr)
    finally:
        s.close()
        print(json.dumps({"app": "hello", "name": a.name, "station": a.name, "mode": s.mode, "ticks": s.ticks,
                          "sent": sent, "heard": dict(heard), "bad_gnss": bad_gnss,
                          "obu": {"accepted": sum(heard.values()), "rejected": dict(rejected)}}), flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
