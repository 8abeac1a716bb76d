"""Benchmark: surrogate BSMs (one per object) against one SDSM (all objects) per 10 Hz cycle.

    python benchmarks/sdsm_vs_bsm.py [--objects 1,5,10,20,40] [--repeats 5] [--cycles 20] [--json PATH] [--quick]

For each object count N, a synthetic object list (N vehicles at random places
within 60 m of the RSU, moving, with a tracker-like covariance) goes through
the RSU app's own stages (rsu_app.bsm_stage.BsmStage, rsu_app.sdsm_stage.
SdsmStage) with a real 1609.2 signer (ECDSA P-256; the full certificate once a
second, its digest otherwise, as the RSU sends), and a receiver verifies
(certificate known after the first) and decodes every frame:

* frames/s and bytes/s on the air: the signed 1609.2 frames of one second
  (10 cycles), counted exactly; lower layers (WSMP, LLC, MAC, PHY preamble)
  add a fixed overhead per frame on top, which only widens SDSM's lead;
* encode+sign per cycle: the stage's send() for the cycle (build from the
  tracks, UPER encode, sign), wall ms, median over repeats of the mean over
  `cycles` cycles;
* verify+decode per cycle: every frame of the cycle verified and decoded to
  the typed message, likewise;
* through the channel model (fmus/channel), three radios:
  - 802.11p at 6 Mb/s, 23 dBm, NIST error model so that PER depends on the
    frame's length, no other traffic: the RSU's own airtime per second (its
    share of the channel busy ratio, MAC header included) and the expected PDR
    of its frames at 100, 200 and 300 m (an SDSM lost loses every object in
    it; a BSM lost loses one);
  - the same channel loaded by other stations to a CBR of 0.6 (the model's
    hidden-terminal and collision losses): PDR at 200 m;
  - C-V2X mode 4 (4 subchannels per subframe, the published BLER table,
    which is for the 190-byte resource, so the PDR does not depend on the
    length): the RSU's own share of the resources per second, a frame taking
    ceil(bytes / 190) subchannel resources at that MCS (a stated
    approximation: a larger transport block uses more subchannels), and the
    PDR at 200 m;
* with --e2e, the case study run twice under the `measured` latency policy
  (the apps' real compute charged in simulated time), once with surrogate
  BSMs (scenarios/ima_case_study.toml) and once with SDSM
  (scenarios/ima_case_study_sdsm.toml), one after the other (the policy
  charges each stage its real compute, so two runs at once on 2 cores would
  charge each the other's load: tried, the SDSM run was then warned late and
  collided): their E2E latency (camera frame to the cav's plan) p50 and p99,
  and their verdicts. About 3 minutes.

Prints a table and writes JSON (default benchmarks/results/sdsm_vs_bsm.json).
"""
from __future__ import annotations

import argparse
import math
import random
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, machine_info, summary, write_report  # noqa: E402
from bridges.geo import GeoOrigin  # noqa: E402
from fmus.channel import errors as channel_errors  # noqa: E402
from fmus.channel.model import ChannelModel  # noqa: E402
from bridges.j2735 import Sdsm  # noqa: E402
from bridges.j2735.bsm import Bsm  # noqa: E402
from bridges.security import PSID_SURROGATE_BSM, ScenarioCA, Signer, Verifier, time64_us  # noqa: E402
from rsu_app.bsm_stage import BsmStage  # noqa: E402
from rsu_app.config import PSID_SDSM_DEFAULT  # noqa: E402
from rsu_app.envelope import Envelope  # noqa: E402
from rsu_app.perception.tracker import TrackState  # noqa: E402
from rsu_app.perception_stage import TrackStamps  # noqa: E402
from rsu_app.sdsm_stage import SdsmStage  # noqa: E402
from rsu_app.timing import LatencyModel  # noqa: E402

DEFAULT_JSON = RESULTS / "sdsm_vs_bsm.json"
RATE_HZ = 10.0
ORIGIN = GeoOrigin()


def tracks(n: int, rng: random.Random) -> list[TrackState]:
    out = []
    for i in range(n):
        r, bearing = rng.uniform(5, 60), rng.uniform(0, 2 * math.pi)
        speed, heading = rng.uniform(0, 20), rng.uniform(-math.pi, math.pi)
        cov = np.diag([rng.uniform(0.02, 0.5), rng.uniform(0.02, 0.5), rng.uniform(0.1, 1.0), rng.uniform(0.1, 1.0)])
        out.append(TrackState(i + 1, 0.0, r * math.cos(bearing), r * math.sin(bearing), speed * math.cos(heading),
                              speed * math.sin(heading), speed, heading, rng.choice(["car", "car", "emergency"]),
                              True, 0, cov))
    return out


def _stages(kind: str, epoch: float, credentials):
    latency = LatencyModel("lockstep", "fixed", {"encode": 0.0, "sign": 0.0})
    envelope = Envelope(Signer(credentials, 1.0))
    if kind == "bsm":
        return BsmStage("rsu", ORIGIN, epoch, b"bench", envelope, latency)
    return SdsmStage("rsu", ORIGIN, epoch, b"bench", envelope, latency, PSID_SDSM_DEFAULT)


def _send(stage, states, t, stamps):
    if isinstance(stage, BsmStage):
        return stage.send(states, t, stamps, True)
    return stage.send(states, t, stamps)


def measure(kind: str, n: int, cycles: int, ca, credentials, epoch: float, seed: int) -> dict:
    """One run: `cycles` cycles of N objects: frames, bytes, ms per cycle both ways."""
    rng = random.Random(seed)
    states = tracks(n, rng)
    stage = _stages(kind, epoch, credentials)
    verifier = Verifier([ca.certificate], max_age_s=3600.0)
    decode = Bsm.decode if kind == "bsm" else Sdsm.decode
    frames = nbytes = 0
    first_second_frames = first_second_bytes = 0
    send_s, receive_s, sizes = [], [], []
    for k in range(cycles):
        t = k / RATE_HZ
        moved = [TrackState(s.id, t, s.x + s.vx * t, s.y + s.vy * t, s.vx, s.vy, s.speed, s.heading, s.label, True, 0,
                            s.cov) for s in states]
        stamps = {s.id: TrackStamps(t - 0.05, t - 0.05, t - 0.01) for s in moved}
        c0 = time.perf_counter()
        txs = _send(stage, moved, t, stamps)
        c1 = time.perf_counter()
        for tx in txs:
            verified = verifier.verify(tx.payload, time64_us(epoch + t))
            decode(verified.payload)
        c2 = time.perf_counter()
        send_s.append(c1 - c0)
        receive_s.append(c2 - c1)
        frames += len(txs)
        nbytes += sum(len(tx.payload) for tx in txs)
        if k < RATE_HZ:  # the first second: one full certificate per signer, digests after
            sizes += [len(tx.payload) for tx in txs]
            first_second_frames += len(txs)
            first_second_bytes += sum(len(tx.payload) for tx in txs)
    return {"frames_per_s": first_second_frames, "bytes_per_s": first_second_bytes, "frame_bytes": sizes,
            "bytes_per_frame_mean": nbytes / frames, "encode_sign_ms": 1e3 * statistics.fmean(send_s),
            "verify_decode_ms": 1e3 * statistics.fmean(receive_s)}


PDR_DISTANCES_M = (100.0, 200.0, 300.0)
LOADED_CBR = 0.6
CV2X_RESOURCE_BYTES = 190  # the DATA field the C-V2X BLER table was published for (fmus/channel/errors.py)


def _pdr(model: ChannelModel, frame_bytes: list[int], distances=PDR_DISTANCES_M) -> dict:
    """The mean expected PDR of these frames at each distance (LOS road)."""
    out = {}
    for d in distances:
        links = model.evaluate(np.zeros((len(frame_bytes), 3)), np.tile([d, 0.0, 0.0], (len(frame_bytes), 1)),
                               packet_bytes=np.asarray(frame_bytes))
        out[f"{d:g}"] = float(np.mean(links.pdr))
    return out


def channel_figures(model: ChannelModel, frame_bytes: list[int]) -> dict:
    """The RSU's own 802.11p airtime in one second of these frames, and their mean expected PDR by distance."""
    p = model.p
    airtime = float(sum(channel_errors.ofdm_80211p_airtime_s(b + p.mac_header_bytes, p.data_rate_bps, p.bandwidth_hz)
                        for b in frame_bytes))
    return {"own_busy_ratio": airtime, "pdr": _pdr(model, frame_bytes)}


def cv2x_figures(model: ChannelModel, frame_bytes: list[int]) -> dict:
    """The RSU's own share of C-V2X mode 4 resources in one second of these frames (subchannels x 1000
    subframes a second; a frame takes ceil(bytes / 190) resources), and the frames' PDR at 200 m."""
    resources = sum(math.ceil(b / CV2X_RESOURCE_BYTES) for b in frame_bytes)
    return {"own_resource_share": resources / (model.p.cv2x_subchannels * 1000.0),
            "pdr": _pdr(model, frame_bytes, (200.0,))}


CASE_STUDIES = {"bsm": "scenarios/ima_case_study.toml", "sdsm": "scenarios/ima_case_study_sdsm.toml"}
E2E_PORTS = {"bsm": 47651, "sdsm": 47652}  # each run its own bus port (the SDSM study extends the BSM one's)


def case_study_e2e() -> dict:
    """Both case studies, one after the other, under the `measured` latency policy: E2E p50/p99 (ms), verdict."""
    out = {}
    with tempfile.TemporaryDirectory(prefix="sdsm-e2e-") as tmp:
        for kind, scen in CASE_STUDIES.items():
            proc = subprocess.run(
                [sys.executable, "-m", "master.cli", "run", str(ROOT / scen), "--out", f"{tmp}/{kind}",
                 "--set", "bridge.latency=measured", "--set", "record.camera=false",
                 "--set", f'bridge.listen=["tcp/127.0.0.1:{E2E_PORTS[kind]}"]', "--quiet", "--no-report"],
                cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=900)
            if proc.returncode != 0:
                raise SystemExit(f"case study with {kind}: v2i run exited {proc.returncode}: {proc.stderr[-2000:]}")
            m = json.loads(Path(f"{tmp}/{kind}/metrics.json").read_text())
            e2e = m["latency_ms"]["e2e"]
            out[kind] = {"e2e_p50_ms": e2e["p50"], "e2e_p99_ms": e2e["p99"], "n": e2e["n"],
                         "collision": m["collision"], "min_gap_m": m["min_gap_m"],
                         "stages_ms": {k: v["p50"] for k, v in m["latency_ms"].items()}}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--objects", default="1,5,10,20,40", help="object counts, comma-separated")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--cycles", type=int, default=20, help="10 Hz cycles per repeat (>= 10: one second)")
    p.add_argument("--json", type=Path, default=DEFAULT_JSON)
    p.add_argument("--quick", action="store_true", help="2 repeats of 10 cycles (a smoke run)")
    p.add_argument("--e2e", action="store_true", help="also run both case studies (measured latency) for E2E")
    args = p.parse_args(argv)
    if args.quick:
        args.repeats, args.cycles = 2, 10
    if args.cycles < RATE_HZ:
        p.error("--cycles: at least 10 (one second of traffic)")
    counts = [int(c) for c in args.objects.split(",") if c.strip()]
    ca = ScenarioCA.create()
    credentials = ca.issue("rsu", [PSID_SURROGATE_BSM, PSID_SDSM_DEFAULT])
    epoch = time.time() + 5.0  # within the certificate's validity, which starts when it is issued
    rows, report = [], {"machine": machine_info(), "rate_hz": RATE_HZ, "repeats": args.repeats,
                        "cycles": args.cycles, "results": {}}
    dsrc = ChannelModel(technology="dsrc", error_model="nist").prepare()
    loaded = ChannelModel(technology="dsrc", error_model="nist", cbr_target=LOADED_CBR).prepare()
    cv2x = ChannelModel(technology="cv2x", error_model="lut").prepare()
    for kind in ("bsm", "sdsm"):  # warm-up: the codec compiles its ASN.1 on first use, caches fill
        measure(kind, 2, int(RATE_HZ), ca, credentials, epoch, seed=0)
    for n in counts:
        entry = {}
        for kind in ("bsm", "sdsm"):
            runs = [measure(kind, n, args.cycles, ca, credentials, epoch, seed=1000 * n + r)
                    for r in range(args.repeats)]
            entry[kind] = {
                "frames_per_s": runs[0]["frames_per_s"], "bytes_per_s": runs[0]["bytes_per_s"],
                "bytes_per_frame_mean": runs[0]["bytes_per_frame_mean"],
                "encode_sign_ms": summary([r["encode_sign_ms"] for r in runs]),
                "verify_decode_ms": summary([r["verify_decode_ms"] for r in runs]),
                "dsrc": channel_figures(dsrc, runs[0]["frame_bytes"]),
                "dsrc_loaded": {"cbr": LOADED_CBR, "pdr": _pdr(loaded, runs[0]["frame_bytes"], (200.0,))},
                "cv2x": cv2x_figures(cv2x, runs[0]["frame_bytes"]),
            }
        report["results"][str(n)] = entry
        b, s = entry["bsm"], entry["sdsm"]
        rows.append((n, b["frames_per_s"], s["frames_per_s"], b["bytes_per_s"], s["bytes_per_s"],
                     b["encode_sign_ms"]["median"], s["encode_sign_ms"]["median"],
                     b["verify_decode_ms"]["median"], s["verify_decode_ms"]["median"],
                     100 * b["dsrc"]["own_busy_ratio"], 100 * s["dsrc"]["own_busy_ratio"],
                     b["dsrc"]["pdr"]["200"], s["dsrc"]["pdr"]["200"], b["dsrc"]["pdr"]["300"],
                     s["dsrc"]["pdr"]["300"], b["dsrc_loaded"]["pdr"]["200"], s["dsrc_loaded"]["pdr"]["200"],
                     100 * b["cv2x"]["own_resource_share"], 100 * s["cv2x"]["own_resource_share"],
                     b["cv2x"]["pdr"]["200"], s["cv2x"]["pdr"]["200"]))
    header = ("objects", "BSM fr/s", "SDSM fr/s", "BSM B/s", "SDSM B/s", "BSM enc+sign ms", "SDSM enc+sign ms",
              "BSM ver+dec ms", "SDSM ver+dec ms", "BSM airtime %", "SDSM airtime %", "BSM PDR 200 m",
              "SDSM PDR 200 m", "BSM PDR 300 m", "SDSM PDR 300 m", f"BSM PDR 200 m CBR {LOADED_CBR}",
              f"SDSM PDR 200 m CBR {LOADED_CBR}", "BSM C-V2X res. %", "SDSM C-V2X res. %", "BSM C-V2X PDR 200 m",
              "SDSM C-V2X PDR 200 m")
    print(" | ".join(header))
    print(" | ".join("---" for _ in header))
    for row in rows:
        print(" | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in row))
    if args.e2e:
        report["case_study_e2e"] = e2e = case_study_e2e()
        print("\ncase study (measured latency) | E2E p50 ms | E2E p99 ms | records | collision | min gap m")
        print("--- | --- | --- | --- | --- | ---")
        for kind, r in e2e.items():
            print(f"{kind} | {r['e2e_p50_ms']:.1f} | {r['e2e_p99_ms']:.1f} | {r['n']} | {r['collision']} | "
                  f"{r['min_gap_m']:.2f}")
    write_report(args.json, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
