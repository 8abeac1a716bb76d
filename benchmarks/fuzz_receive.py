"""Fuzz campaign: mutated and random frames through the AV's receive path, 0 crashes, every rejection with a reason.

    python benchmarks/fuzz_receive.py [--frames 1000000] [--seed 1] [--json PATH] [--quick]

The path is the AV app's own: `av_app.obu.Obu.receive` (1609.2 verification
with `bridges.security.Verifier`, built as av_app.app builds it from the
app's [security] defaults; J2735 decoding; the typed BSM/SPaT/MAP and the
conversion to local metres). Frames, at 10 ms steps of simulated time,
arriving 2 ms after their generation time:

* fresh: a new signed surrogate BSM with random content (the station's full
  certificate once a second, its digest otherwise), before about one input
  in twenty; every other input is made from the latest fresh frame;
* replay: that frame again;
* bitflip / overwrite / truncate / insert / delete / extend / splice:
  that frame with 1-3 bits flipped, a byte overwritten, cut short, 1-8
  random bytes put in or taken out, 1-64 bytes appended, or the head of one
  valid frame joined to the tail of another at random cut points;
* random: 0-400 random bytes; random-after-header: a valid frame's first
  2-12 bytes and random bytes after them;
* signed-mutant: the BSM's UPER bytes mutated as above and then validly
  signed, so the mutation reaches the J2735 decoder and the typed BSM.

Outcomes are counted by category and reason (`accepted:<kind>` or the
rejection reason the OBU tallies). A crash is an exception that leaves
`Obu.receive` other than its `Rejected`, or a rejection the OBU's own safety
net produced from an unexpected exception type (a `Rejected` whose context is
not the verifier's VerificationError or the codec's J2735Error); each is
printed with its input hex and kept in the JSON. A rejection with a reason
the OBU does not document, or without a detail, counts as unexplained.
The goal line is `0 crashes, 0 unexplained`.

`--seed` fixes the mutation choices; ECDSA signatures (random k) and the
keys differ from run to run, which is why every crash keeps its input.
Default 10^6 frames: several minutes on one core.
"""
from __future__ import annotations

import argparse
import os
import random
import sys
import tempfile
import time
import traceback
from collections import Counter, defaultdict
from datetime import datetime, timedelta, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import asn1tools  # noqa: E402
import cryptography  # noqa: E402

from av_app.config import build  # noqa: E402
from av_app.obu import Obu, Rejected  # noqa: E402
from benchmarks.common import RESULTS, machine_info, write_report  # noqa: E402
from bridges.geo import GeoOrigin  # noqa: E402
from bridges.j2735 import J2735Error  # noqa: E402
from bridges.j2735.bsm import EmergencyInfo, surrogate_bsm  # noqa: E402
from bridges.security import (PSID_SURROGATE_BSM, Rejection, ScenarioCA, Signer, VerificationError,  # noqa: E402
                              Verifier, load_certificate, time64_us)
from bridges.v2x import unix_time  # noqa: E402

DEFAULT_JSON = RESULTS / "fuzz_receive.json"
STEP_S = 0.01  # simulated time between valid frames
DELAY_S = 0.002  # arrival after generation
CATEGORIES = {  # name: weight ("fresh", a new valid frame, comes before ~5% of the inputs)
    "replay": 2, "bitflip": 16, "overwrite": 8, "truncate": 8, "insert": 8, "delete": 8, "extend": 6, "splice": 10,
    "random": 8, "random-after-header": 8, "signed-mutant": 18,
}
# reasons the OBU documents (av_app/obu.py): the verifier's, then its own
OBU_REASONS = {r.value for r in Rejection} | {"bad-time", "no-trust-anchor", "undecodable", "unsupported",
                                                "psid-mismatch", "incomplete", "stale"}
EXPECTED_CONTEXTS = (VerificationError, J2735Error)
MAX_CRASH_RECORDS = 50


def mutate(data: bytes, rng: random.Random, kind: str, other: bytes = b"") -> bytes:
    """One byte-level mutation of `data` (`other` is the second frame for a splice)."""
    buf = bytearray(data)
    if kind == "bitflip":
        for _ in range(rng.randint(1, 3)):
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
    elif kind == "overwrite":
        buf[rng.randrange(len(buf))] = rng.randrange(256)
    elif kind == "truncate":
        del buf[rng.randrange(len(buf)):]
    elif kind == "insert":
        at = rng.randrange(len(buf) + 1)
        buf[at:at] = rng.randbytes(rng.randint(1, 8))
    elif kind == "delete":
        at = rng.randrange(len(buf))
        del buf[at:at + rng.randint(1, 8)]
    elif kind == "extend":
        buf += rng.randbytes(rng.randint(1, 64))
    elif kind == "splice":
        buf = buf[:rng.randrange(len(buf) + 1)] + other[rng.randrange(len(other) + 1):]
    else:
        raise ValueError(kind)
    return bytes(buf)


BYTE_MUTATIONS = ("bitflip", "overwrite", "truncate", "insert", "delete", "extend")


def random_bsm(rng: random.Random, k: int, epoch: float, t: float):
    maybe = lambda value: value if rng.random() < 0.8 else None  # noqa: E731
    emergency = None
    if rng.random() < 0.3:
        emergency = EmergencyInfo(siren=rng.choice(["unavailable", "notInUse", "inUse"]),
                                  lightbar=rng.choice(["unavailable", "inUse", "freqStops"]),
                                  response_type=rng.choice([None, "emergency", "pursuit"]))
    return surrogate_bsm(
        rng.randrange(64), b"fuzz", msg_count=k % 128,
        sec_mark_ms=int(round((unix_time(t, epoch) % 60) * 1000)) % 60000,
        latitude=42.3 + rng.uniform(-1e-3, 1e-3), longitude=-83.7 + rng.uniform(-1e-3, 1e-3),
        elevation=maybe(rng.uniform(0, 400)), speed=maybe(rng.uniform(0, 40)), heading=maybe(rng.uniform(0, 359)),
        yaw_rate=rng.uniform(-30, 30), width=maybe(rng.uniform(1.5, 2.6)), length=maybe(rng.uniform(3, 12)),
        emergency=emergency)


class Campaign:
    """The receive path under test and the tallies."""

    def __init__(self, seed: int):
        self.rng = random.Random(seed)
        now = datetime.now(timezone.utc)
        self.epoch = now.timestamp()
        ca = ScenarioCA.create(start=now - timedelta(hours=1))
        station = ca.issue("rsu", [PSID_SURROGATE_BSM], start=now - timedelta(hours=1))
        self.signer = Signer(station)  # periodic: full certificate once a second
        self.payload_signer = Signer(station, signer_identifier="digest")
        with tempfile.TemporaryDirectory() as keys:  # the app's config names the CA certificate's file
            ca.credentials.save(keys)
            cfg = build({"security": {"trust_anchor": str(Path(keys) / f"{ca.certificate.name}.cert")}})
            sec = cfg.security  # as av_app.app.AvApp._verifier builds it
            verifier = Verifier([load_certificate(cfg.path(sec.trust_anchor))], max_age_s=sec.max_age_s,
                                max_future_s=sec.max_future_s, allow_unsecured=sec.allow_unsecured)
        self.obu = Obu(cfg.obu, GeoOrigin(), self.epoch, verifier)
        self.outcomes: dict[str, Counter] = defaultdict(Counter)  # category -> outcome -> count
        self.seconds: Counter = Counter()  # category -> time in receive
        self.crashes: list[dict] = []
        self.crash_count = 0
        self.unexplained = 0
        self.frames = 0

    def run(self, frames: int, progress_every: int) -> None:
        names, weights = list(CATEGORIES), list(CATEGORIES.values())
        rng, k, t = self.rng, 0, 0.0
        previous = current = None
        start = time.perf_counter()
        while self.frames < frames:
            if current is None or rng.random() < 0.05:  # a new valid frame every ~20 inputs
                k += 1
                t = k * STEP_S
                generated = time64_us(unix_time(t, self.epoch))
                payload = random_bsm(rng, k, self.epoch, t).encode()
                previous, current = current, (payload, self.signer.sign(payload, PSID_SURROGATE_BSM, generated))
                self.feed("fresh", current[1], t)  # every valid frame is received once (certificates are learnt)
                continue
            category = rng.choices(names, weights)[0]
            payload, frame = current
            if category == "replay":
                data = frame
            elif category in BYTE_MUTATIONS:
                data = mutate(frame, rng, category)
            elif category == "splice":
                data = mutate(frame, rng, "splice", (previous or current)[1])
            elif category == "random":
                data = rng.randbytes(rng.randint(0, 400))
            elif category == "random-after-header":
                data = frame[:rng.randint(2, 12)] + rng.randbytes(rng.randint(0, 300))
            else:  # signed-mutant
                mutant = mutate(payload, rng, rng.choice(BYTE_MUTATIONS))
                data = self.payload_signer.sign(mutant, PSID_SURROGATE_BSM, time64_us(unix_time(t, self.epoch)))
            self.feed(category, data, t)
            if progress_every and self.frames % progress_every == 0:
                rate = self.frames / (time.perf_counter() - start)
                print(f"  {self.frames:>9,} frames, {rate:,.0f}/s, crashes {self.crash_count}", flush=True)

    def feed(self, category: str, data: bytes, t: float) -> None:
        self.frames += 1
        w0 = time.perf_counter()
        try:
            accepted = self.obu.receive(data, t + DELAY_S)
        except Rejected as exc:
            self.seconds[category] += time.perf_counter() - w0
            context = exc.__context__
            if context is not None and not isinstance(context, EXPECTED_CONTEXTS):
                self.crash(category, data, context, f"caught by the OBU as {exc.reason!r}")
                return
            if exc.reason not in OBU_REASONS or not exc.detail:
                self.unexplained += 1
                self.outcomes[category][f"unexplained:{exc.reason}"] += 1
                return
            self.outcomes[category][exc.reason] += 1
            return
        except Exception as exc:  # noqa: BLE001 - anything else is what this campaign looks for
            self.seconds[category] += time.perf_counter() - w0
            self.crash(category, data, exc, "escaped Obu.receive")
            return
        self.seconds[category] += time.perf_counter() - w0
        self.outcomes[category][f"accepted:{accepted.kind}"] += 1

    def crash(self, category: str, data: bytes, exc: BaseException, how: str) -> None:
        self.crash_count += 1
        self.outcomes[category][f"CRASH:{type(exc).__name__}"] += 1
        if len(self.crashes) < MAX_CRASH_RECORDS:
            record = {"category": category, "how": how, "type": type(exc).__name__, "message": str(exc)[:300],
                      "where": traceback.format_exception(exc)[-2].strip()[:300] if exc.__traceback__ else "",
                      "hex": data.hex()}
            self.crashes.append(record)
            print(f"CRASH {record['type']} ({how}, {category}): {record['message']}\n  input {record['hex']}",
                  flush=True)


def print_table(campaign: Campaign, wall_s: float) -> None:
    reasons = Counter()
    for counts in campaign.outcomes.values():
        reasons.update(counts)
    print(f"\n{campaign.frames:,} frames through Obu.receive in {wall_s:.1f} s "
          f"({campaign.frames / wall_s:,.0f} frames/s)\n")
    print(f"{'category':<20} {'frames':>9} {'us/frame':>9}  top outcomes")
    for category in ("fresh", *CATEGORIES):
        counts = campaign.outcomes.get(category, Counter())
        n = sum(counts.values())
        if not n:
            continue
        top = ", ".join(f"{reason} {count:,}" for reason, count in counts.most_common(4))
        print(f"{category:<20} {n:>9,} {campaign.seconds[category] / n * 1e6:>9.0f}  {top}")
    print(f"\n{'outcome':<32} {'count':>9} {'share':>7}")
    for reason, count in sorted(reasons.items(), key=lambda item: -item[1]):
        print(f"{reason:<32} {count:>9,} {count / campaign.frames:>7.2%}")
    verdict = "PASS" if campaign.crash_count == 0 and campaign.unexplained == 0 else "FAIL"
    print(f"\ngoal: 0 crashes, 0 unexplained rejections: crashes {campaign.crash_count}, "
          f"unexplained {campaign.unexplained}  {verdict}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=10**6, help="frames to feed (default 10^6)")
    ap.add_argument("--seed", type=int, default=1, help="fixes the mutation choices (default 1)")
    ap.add_argument("--json", type=Path, default=DEFAULT_JSON)
    ap.add_argument("--quick", action="store_true", help="20,000 frames: a smoke test")
    args = ap.parse_args(argv)
    frames = 20_000 if args.quick else args.frames
    if frames < 1:
        ap.error("--frames: give at least 1")
    info = machine_info(asn1tools=asn1tools.__version__, cryptography=cryptography.__version__)
    campaign = Campaign(args.seed)
    print(f"fuzzing the AV receive path with {frames:,} frames (seed {args.seed})", flush=True)
    start = time.perf_counter()
    campaign.run(frames, progress_every=max(frames // 10, 1000))
    wall_s = time.perf_counter() - start
    print_table(campaign, wall_s)
    reasons = Counter()
    for counts in campaign.outcomes.values():
        reasons.update(counts)
    obu_total = sum(campaign.obu.rejected.values()) + sum(campaign.obu.accepted.values())
    report = {
        "frames": campaign.frames, "seed": args.seed, "wall_s": wall_s,
        "frames_per_s": campaign.frames / wall_s,
        "crashes": campaign.crash_count, "unexplained": campaign.unexplained,
        "goal_pass": campaign.crash_count == 0 and campaign.unexplained == 0,
        "outcomes": dict(reasons.most_common()),
        "by_category": {c: dict(v.most_common()) for c, v in campaign.outcomes.items()},
        "us_per_frame_by_category": {c: campaign.seconds[c] / sum(v.values()) * 1e6
                                     for c, v in campaign.outcomes.items() if sum(v.values())},
        "obu_tally": {"received": campaign.obu.received, "counted": obu_total,
                      "accepted": dict(campaign.obu.accepted), "rejected": dict(campaign.obu.rejected)},
        "crash_records": campaign.crashes,
        "machine": {**info, "loadavg_end": list(os.getloadavg())},
    }
    write_report(args.json, report)
    return 0 if report["goal_pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
