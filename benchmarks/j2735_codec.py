"""Benchmark: microseconds per BSM to encode, decode, sign, verify, and the RSU's send stage.

    python benchmarks/j2735_codec.py [--n 2000] [--repeats 5] [--json PATH] [--quick]

Cases, all on the same surrogate BSM (core data + SpecialVehicleExtensions,
the message the RSU sends for a tracked vehicle), in one process and run:

* floor: a plain `asn1tools.compile_files(module, "uper")` encoding and
  decoding the frame and the inner BSM (two calls each, as any J2735 codec
  must), with no checks;
* codec: `J2735Codec.encode/decode` (range checks, part II second stage,
  error wrapping, frame length) on asn1tools values;
* typed: `Bsm.encode()` from SI units and `Bsm.decode()` back;
* sign / verify: the 1609.2-style envelope (ECDSA P-256, SHA-256); verify
  with the station certificate already known (digest signer);
* stage: typed encode + sign + `sendto` on a loopback UDP socket, the RSU's
  whole encode+sign+send stage (budget 1 ms; the seed paper measured 8.1 ms,
  ANCHORS I6), beside a bare `sendto` of the same bytes.

Each figure is the median over repeats of (loop time / n); ratios are taken
against the floor within the same run. Results go to JSON (default
benchmarks/results/j2735_codec.json).
"""
from __future__ import annotations

import argparse
import socket
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
# (with an editable install ROOT is already on the path, behind this folder)
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import asn1tools  # noqa: E402
import cryptography  # noqa: E402

from benchmarks.common import RESULTS, machine_info, summary, write_report  # noqa: E402
from bridges.j2735.bsm import Bsm, EmergencyInfo, surrogate_bsm  # noqa: E402
from bridges.j2735.codec import BUILTIN_MODULE, default_codec  # noqa: E402
from bridges.security import PSID_SURROGATE_BSM, ScenarioCA, Signer, Verifier, time64_us  # noqa: E402

BUDGET_US = 1000.0
PAPER_US = 8100.0
DEFAULT_JSON = RESULTS / "j2735_codec.json"


def sample_bsm() -> Bsm:
    return surrogate_bsm(42, b"bench", msg_count=17, sec_mark_ms=31250, latitude=42.2808256,
                         longitude=-83.7430378, elevation=256.4, speed=16.67, heading=92.5, width=2.5,
                         length=6.5, accel_long=-0.5, yaw_rate=1.2,
                         emergency=EmergencyInfo(siren="inUse", lightbar="inUse", response_type="emergency"))


def per_call_us(fn, n: int) -> float:
    start = time.perf_counter()
    for _ in range(n):
        fn()
    return (time.perf_counter() - start) / n * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=2000, help="calls per timed loop")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path, default=DEFAULT_JSON)
    ap.add_argument("--quick", action="store_true", help="a few hundred calls: a smoke test")
    args = ap.parse_args(argv)
    n, repeats = (200, 2) if args.quick else (args.n, args.repeats)

    codec = default_codec()
    floor = asn1tools.compile_files(str(BUILTIN_MODULE), "uper")
    bsm = sample_bsm()
    message = bsm.to_asn1()
    frame_bytes = bsm.encode()
    part_ii = message["partII"][0]
    raw_part = floor.encode("SpecialVehicleExtensions", part_ii["partII-Value"])
    raw_message = dict(message, partII=[{"partII-Id": 1, "partII-Value": raw_part}])

    def floor_encode():
        inner = floor.encode("SpecialVehicleExtensions", part_ii["partII-Value"])
        value = floor.encode("BasicSafetyMessage", dict(raw_message, partII=[{"partII-Id": 1, "partII-Value": inner}]))
        return floor.encode("MessageFrame", {"messageId": 20, "value": value})

    def floor_decode():
        frame = floor.decode("MessageFrame", frame_bytes)
        inner = floor.decode("BasicSafetyMessage", frame["value"])
        return floor.decode("SpecialVehicleExtensions", inner["partII"][0]["partII-Value"])

    assert floor_encode() == frame_bytes

    ca = ScenarioCA.create()
    credentials = ca.issue("rsu1", [PSID_SURROGATE_BSM])
    signer = Signer(credentials, certificate_interval_s=1e9)
    now = time64_us(time.time())
    verifier = Verifier([ca.certificate], max_age_s=1e9, max_future_s=1e9)
    verifier.verify(signer.sign(frame_bytes, PSID_SURROGATE_BSM, now), now)  # learn the certificate
    counter = iter(range(1, 10**9))

    def sign():
        return signer.sign(frame_bytes, PSID_SURROGATE_BSM, now + next(counter))

    signed_pool = [signer.sign(frame_bytes, PSID_SURROGATE_BSM, now + 10**7 + i) for i in range(n * repeats + n)]
    pool = iter(signed_pool)

    def verify():
        return verifier.verify(next(pool), now)

    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    address = receiver.getsockname()
    envelope = sign()

    def drain():
        receiver.setblocking(False)
        try:
            while True:
                receiver.recv(4096)
        except BlockingIOError:
            pass

    def stage():
        sender.sendto(signer.sign(sample_bsm().encode(), PSID_SURROGATE_BSM, now + next(counter)), address)

    def bare_send():
        sender.sendto(envelope, address)

    cases = {
        "floor encode (asn1tools)": floor_encode,
        "floor decode (asn1tools)": floor_decode,
        "codec encode": lambda: codec.encode(20, message),
        "codec decode": lambda: codec.decode(frame_bytes),
        "typed encode (Bsm.encode)": lambda: sample_bsm().encode(),
        "typed decode (Bsm.decode)": lambda: Bsm.decode(frame_bytes),
        "sign (ECDSA P-256)": sign,
        "verify (known signer)": verify,
        "bare UDP sendto": bare_send,
        "stage: typed encode + sign + sendto": stage,
    }
    times: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, fn in cases.items():
            times[name].append(per_call_us(fn, n))
            drain()
    receiver.close()
    sender.close()

    results = {name: summary(values) for name, values in times.items()}
    med = {name: r["median"] for name, r in results.items()}
    ratios = {
        "codec encode / floor encode": med["codec encode"] / med["floor encode (asn1tools)"],
        "codec decode / floor decode": med["codec decode"] / med["floor decode (asn1tools)"],
        "stage / budget": med["stage: typed encode + sign + sendto"] / BUDGET_US,
        "paper / stage": PAPER_US / med["stage: typed encode + sign + sendto"],
    }
    print(f"J2735 surrogate BSM: {len(frame_bytes)} bytes, signed envelope {len(envelope)} bytes "
          f"(digest signer); n={n}, repeats={repeats}")
    print(f"{'case':40s} {'median us':>10s} {'min us':>10s}")
    for name, r in results.items():
        print(f"{name:40s} {r['median']:10.1f} {r['min']:10.1f}")
    print()
    for name, value in ratios.items():
        print(f"{name:40s} {value:10.2f}")
    verdict = "PASS" if med["stage: typed encode + sign + sendto"] <= BUDGET_US else "FAIL"
    print(f"goal: encode+sign+send <= {BUDGET_US:.0f} us (paper: {PAPER_US:.0f} us): {verdict}")

    report = {
        "benchmark": "j2735_codec",
        "machine": machine_info(asn1tools=asn1tools.__version__, cryptography=cryptography.__version__),
        "n": n, "repeats": repeats,
        "bsm_bytes": len(frame_bytes), "envelope_bytes": len(envelope),
        "results_us": results, "ratios": ratios,
        "budget_us": BUDGET_US, "paper_us": PAPER_US, "verdict": verdict,
    }
    write_report(args.json, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
