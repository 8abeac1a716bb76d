"""Benchmark: the RSU app's stages against the seed paper's RSU computer (ANCHORS I6, I7).

    python benchmarks/rsu_app.py [--threads 1 2] [--backends onnx torch classical] [--realtime-seconds 8]
                                 [--tune] [--json PATH] [--quick]

1. Stage 1 (camera frame -> objects: detect + project, as `PerceptionStage.process` does it inside the
   app, plus the tracker update) per detector backend and CPU thread count, p50/p99 in ms over the
   case study's rendered camera sequence (81 frames, 640x480), beside the seed paper's 3600 ms on an
   8-core CPU. Goal: p50 <= 20 ms with onnx on 1 thread.
2. Stage 2 (objects -> signed frame: surrogate BSM built, UPER-encoded, 1609.2-signed with a scenario CA
   certificate), p50/p99 per BSM, beside the paper's 8.1 ms; SPaT and MAP the same way. Goal: <= 1 ms.
3. Sustained rate in realtime: `v2i run` of the case study in realtime (rtf 1) with the app as a
   started participant (onnx, 1 thread) for --realtime-seconds: frames the app processed per second
   of the 10 Hz camera, frames it skipped, BSMs per second per track, its stage figures.
4. With --tune: the operating-point sweep that chose the app's perception defaults, on
   tests/scenarios/rsu_tuning.toml (never on the case study the tests score): for each score
   threshold, range limit, duplicate-merge radius and confirmation count, the false-track BSMs per
   minute (BSMs > 3 m from every vehicle), duplicate BSMs per minute (a second BSM on one vehicle in a
   slot), coverage (slots in which a vehicle visible within 60 m had a BSM within 3 m), median position
   and p90 heading errors; the selected point (fewest false + duplicate BSMs, then most coverage, then
   the smallest error) and the same figures on the case study at the defaults.

Results go to JSON (default benchmarks/results/rsu_app.json). `--quick`: onnx only, 1 thread, 3 s realtime.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import subprocess
import sys
import tempfile
import time
import uuid
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parent.parent
# run as a plain script from anywhere: the project first, and not this folder (benchmarks/bridges.py would
# shadow the bridges package)
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, machine_info, write_report  # noqa: E402

PAPER_STAGE1_MS = 3600.0  # ANCHORS I6: detection on an 8-core CPU
PAPER_STAGE2_MS = 8.1     # ANCHORS I6: BSM encode + transfer
CASE = ROOT / "scenarios" / "ima_world.toml"
TUNING = ROOT / "tests" / "scenarios" / "rsu_tuning.toml"
MATCH_M = 3.0
NEAR_M = 60.0
MIN_VISIBLE_PIXELS = 40


def pct(values, q) -> float:
    return float(np.percentile(np.asarray(values, float), q)) if len(values) else float("nan")


# -- the camera sequence, rendered once ---------------------------------------------------------------------
@dataclasses.dataclass
class Sequence:
    frames: list       # SimpleNamespace(camera, frame_id, t, rgb, K, R_wc, position)
    truth: list        # per frame: {vehicle: (x, y, yaw, visible)}
    background: np.ndarray
    intersection: dict
    names: list


def render_sequence(scenario: Path, stop: float | None = None) -> Sequence:
    """The scenario's first camera at its rate, vehicles at constant speed (x0, y0, yaw0, v0), with truth."""
    from master.scenario import load_scenario
    from master.world.world import World

    sc = load_scenario(scenario)
    spec = sc.world.cameras[0]
    stop = sc.time.stop if stop is None else stop
    names = list(sc.world.vehicles)
    frames, truth = [], []
    with World(sc.world) as w:
        cam = w.cameras[spec.name]
        for n in names:
            w.pose_vehicle(n, 5000.0, 5000.0, 0.0, 0.0)
        background = cam.render(0.0).rgb.copy()
        for k in range(int(round(stop * spec.rate_hz)) + 1):
            t = k / spec.rate_hz
            row = {}
            for n in names:
                p = sc.instances[n].parameters
                x0, y0, yaw, v = (float(p.get(q, 0.0)) for q in ("x0", "y0", "yaw0", "v0"))
                x, y = x0 + v * t * math.cos(yaw), y0 + v * t * math.sin(yaw)
                w.pose_vehicle(n, x, y, yaw, v)
                d = sc.world.vehicles[n].centre_offset
                row[n] = [x + d * math.cos(yaw), y + d * math.sin(yaw), yaw, v]
            f = cam.render(t)
            for n in names:
                row[n].append(bool(np.count_nonzero(f.seg == w.scene.vehicle_ids[n]) >= MIN_VISIBLE_PIXELS))
            frames.append(SimpleNamespace(camera=spec.name, frame_id=k, t=t, rgb=f.rgb, K=cam.K, R_wc=cam.R_wc,
                                          position=cam.position))
            truth.append(row)
    ix = dataclasses.asdict(sc.world.intersection)
    return Sequence(frames, truth, background, ix, names)


def truth_at(seq: Sequence, t: float) -> dict:
    """Vehicle centres at time t (constant speed from frame 0), with the visibility of the nearest frame."""
    k = min(len(seq.truth) - 1, max(0, int(round(t * 10))))
    out = {}
    for n, (x, y, yaw, v, _) in seq.truth[0].items():
        out[n] = (x + v * t * math.cos(yaw), y + v * t * math.sin(yaw), yaw, seq.truth[k][n][4])
    return out


# -- 1: stage 1 --------------------------------------------------------------------------------------------
def stage1(seq: Sequence, backend: str, threads: int) -> dict:
    from rsu_app.config import Settings
    from rsu_app.app import make_rsu_detector
    from rsu_app.perception.tracker import Tracker
    from rsu_app.perception_stage import DetectionZone, PerceptionStage

    s = Settings()
    s.detector.backend, s.detector.threads = backend, threads
    detector = make_rsu_detector(s)
    if backend == "classical":
        detector.set_background(seq.background)
    stage = PerceptionStage(detector, Tracker(), DetectionZone(NEAR_M, seq.intersection, True, 1.5),
                            s.detector.score_threshold)
    totals = []
    for f in seq.frames:
        result = stage.process(f, f.t)
        track_s = stage.apply([result]) if result is not None else 0.0
        totals.append(result.compute_s + track_s)
    ms = [v * 1000 for v in totals]
    return {"backend": backend, "threads": threads, "p50_ms": pct(ms, 50), "p99_ms": pct(ms, 99),
            "max_ms": max(ms), "n": len(ms), "fps_p50": 1000 / pct(ms, 50),
            "vs_paper": PAPER_STAGE1_MS / pct(ms, 50)}


# -- 2: stage 2 --------------------------------------------------------------------------------------------
def stage2(n: int) -> dict:
    from bridges.geo import GeoOrigin
    from bridges.security import ScenarioCA, Signer
    from rsu_app.bsm_stage import BsmStage
    from rsu_app.envelope import Envelope
    from rsu_app.intersection_map import intersection_geometry
    from rsu_app.perception.tracker import TrackState
    from rsu_app.spat_stage import MapStage, SpatStage
    from rsu_app.timing import LatencyModel
    from bridges import ab3418

    ca = ScenarioCA.create()
    creds = ca.issue("rsu", [0x7F, 0x82])
    envelope = Envelope(Signer(creds))
    latency = LatencyModel("lockstep", "measured")
    epoch = time.time()
    bsm = BsmStage("rsu", GeoOrigin(), epoch, b"bench", envelope, latency)
    state = TrackState(7, 1.0, 1.75, -20.0, 0.0, 8.3, 8.3, math.pi / 2, "emergency", True, 0,
                       np.diag([0.2, 0.3, 0.5, 0.5]))
    for i in range(20):  # warm-up: the codec compiles its ASN.1 and the signer loads on first use
        bsm.send([state], 0.1 * i, {}, True)
    bsm.encode_s.clear()
    bsm.sign_s.clear()
    per_bsm = []
    for i in range(n):
        tx = bsm.send([dataclasses.replace(state, y=-20.0 + 0.83 * i)], 1.0 + 0.1 * i, {}, True)[0]
        per_bsm.append(tx.compute_s["encode"] + tx.compute_s["sign"])
    spat = SpatStage("rsu", epoch, envelope, latency, intersection_id=1, signal_groups=[2, 4, 6, 8], baud=9600,
                     max_age_s=1e9)
    spat.on_status(ab3418.LongStatus8(greens=0b100010, phase_a=2, phase_b=6, ttc_a_min=100, ttc_a_max=150), 40, 0.0)
    per_spat = [sum(spat.send(0.1 * i).compute_s.values()) for i in range(max(50, n // 5))]
    world = {"intersection": {"road_width": 7.0, "lane_width": 3.5, "arm_length": 120.0}, "signals": []}
    mp = MapStage("rsu", epoch, envelope, latency, intersection_geometry(world, GeoOrigin(), 1, 1, 1.0), 1)
    per_map = [sum(mp.send(float(i)).compute_s.values()) for i in range(max(20, n // 20))]
    out = {}
    for name, values in (("bsm", per_bsm), ("spat", per_spat), ("map", per_map)):
        ms = [v * 1000 for v in values]
        out[name] = {"p50_ms": pct(ms, 50), "p99_ms": pct(ms, 99), "n": len(ms),
                     "vs_paper": PAPER_STAGE2_MS / pct(ms, 50)}
    enc = [e * 1000 for e in bsm.encode_s]
    sig = [s * 1000 for s in bsm.sign_s]
    out["bsm"].update(encode_p50_ms=pct(enc, 50), sign_p50_ms=pct(sig, 50))
    return out


# -- 3: realtime ---------------------------------------------------------------------------------------------
def realtime_run(seconds: float, backend: str = "onnx") -> dict:
    from bridges.timesync.bench import free_tcp_port

    with tempfile.TemporaryDirectory(prefix="rsu-bench-") as tmp:
        tmp = Path(tmp)
        subprocess.run([sys.executable, "-m", "master.cli", "pki", "init", str(tmp / "keys"), "--station",
                        "rsu:0x7f,0x82"], check=True, capture_output=True, cwd=ROOT)
        text = CASE.read_text().replace('mode = "lockstep"', 'mode = "realtime"\nrtf = 1.0\noverrun = "slip"')
        text = text.replace("stop = 8.0", f"stop = {seconds}")
        text += f"""
[bridge]
transport = "zenoh"
prefix = "bench/rsu-{uuid.uuid4().hex[:8]}"
listen = ["tcp/127.0.0.1:{free_tcp_port()}"]
join_timeout_s = 60.0
[participants.rsu]
role = "rsu_app"
timeout_s = 60.0
command = ["{{python}}", "-m", "rsu_app", "--config", "{ROOT / 'scenarios' / 'apps' / 'rsu.toml'}", "--pki-dir", "keys",
           "--detector", "{backend}", "--set", "health.stats_every_s=0"]
"""
        (tmp / "rt.toml").write_text(text)
        r = subprocess.run([sys.executable, "-m", "master.cli", "run", str(tmp / "rt.toml"), "--out",
                            str(tmp / "out"), "--quiet"], capture_output=True, text=True, cwd=tmp, timeout=600)
        if r.returncode != 0:
            return {"error": (r.stdout + r.stderr)[-2000:]}
        log = (tmp / "out" / "participant-rsu.log").read_text().strip().splitlines()
        summary = json.loads(next(line for line in reversed(log) if line.startswith("{")))
        meta = json.loads((tmp / "out" / "metadata.json").read_text())
    frames = summary["frames"]
    camera = summary["camera"]
    processed = frames["processed"]
    offered = camera["received"] + camera["skipped"]
    bsm = summary["bsm_by_track"]
    return {"backend": backend, "seconds": seconds, "camera_fps": offered / seconds,
            "processed_fps": processed / seconds, "frames_processed": processed, "frames_offered": offered,
            "frames_skipped": camera["skipped"], "dropped_busy": frames["dropped_busy"],
            "stage1_compute_ms": summary["stage1"]["compute_ms"], "stage2_compute_ms": summary["stage2"]["compute_ms"],
            "bsms": summary["bsm_sent"], "bsm_tracks": len(bsm), "slots_skipped_late": summary["slots_skipped_late"],
            "rtf_achieved": meta.get("realtime", {}).get("rtf_achieved") or meta.get("rtf_achieved")}


# -- 4: operating points -------------------------------------------------------------------------------------
class CachedDetector:
    """The real detector's boxes per frame (computed once at a low threshold), replayed for every point."""

    name = "cached"

    def __init__(self, boxes):
        self.boxes = boxes

    def detect(self, rgb):
        return self.boxes[rgb.index]


class FrameIndex:
    shape = (480, 640, 3)

    def __init__(self, index, shape):
        self.index, self.shape = index, shape


def replay(seq: Sequence, boxes, score: float, max_range: float, merge: float, hits: int, window: int = 5,
           max_missed: int = 5) -> dict:
    """The app's core on the cached detections at one operating point; scored against the truth."""
    from rsu_app.core import RsuCore
    from rsu_app.perception.tracker import Tracker, TrackerConfig
    from rsu_app.perception_stage import DetectionZone, PerceptionStage
    from rsu_app.timing import LatencyModel

    class Recorder:  # stands in for the BSM stage: what would be sent, per slot
        def __init__(self):
            self.slots = []

        def send(self, states, t, stamps, sequential):
            self.slots.append((t, [(s.x, s.y, s.heading) for s in states]))
            return []

    stage = PerceptionStage(CachedDetector(boxes), Tracker(TrackerConfig(confirm_hits=hits, confirm_window=window,
                                                                         max_missed=max_missed)),
                            DetectionZone(max_range, seq.intersection, True, 1.5), score, merge)
    rec = Recorder()
    core = RsuCore(LatencyModel("lockstep", "fixed", {"detect": 0.05}), stage, rec)
    shape = seq.frames[0].rgb.shape
    fi = 0
    for k in range(int(round(seq.frames[-1].t / 0.01)) + 1):
        t = round(k * 0.01, 9)
        frames = []
        while fi < len(seq.frames) and seq.frames[fi].t <= t + 1e-9:
            f = seq.frames[fi]
            frames.append(SimpleNamespace(camera=f.camera, frame_id=fi, t=f.t, rgb=FrameIndex(fi, shape), K=f.K,
                                          R_wc=f.R_wc, position=f.position))
            fi += 1
        core.step(t, frames)
    cam = seq.frames[0].position
    false = dup = 0
    errs, hdgs = [], []
    seen = covered = 0
    by_vehicle = Counter()
    for t, states in rec.slots:
        truth = truth_at(seq, t)
        matched = Counter()
        for x, y, h in states:
            n, (tx, ty, yaw, _) = min(truth.items(), key=lambda kv: math.hypot(x - kv[1][0], y - kv[1][1]))
            e = math.hypot(x - tx, y - ty)
            if e > MATCH_M:
                false += 1
                continue
            matched[n] += 1
            if matched[n] > 1:
                dup += 1
                continue
            by_vehicle[n] += 1
            errs.append(e)
            if h is not None:
                hdgs.append(math.degrees(abs(math.remainder(h - yaw, math.tau))))
        for n, (tx, ty, _, visible) in truth.items():
            if visible and math.hypot(tx - cam[0], ty - cam[1]) <= NEAR_M:
                seen += 1
                covered += matched[n] > 0
    minutes = seq.frames[-1].t / 60.0
    return {"false_per_min": false / minutes, "dup_per_min": dup / minutes, "coverage": covered / max(seen, 1),
            "pos_median_m": float(np.median(errs)) if errs else float("nan"),
            "hdg_p90_deg": pct(hdgs, 90), "bsms": sum(len(s) for _, s in rec.slots),
            "bsms_per_vehicle": dict(by_vehicle)}


def tune(seq_tune: Sequence, seq_case: Sequence, quick: bool) -> dict:
    from rsu_app.config import Settings
    from rsu_app.app import make_rsu_detector

    s = Settings()
    s.detector.score_threshold = 0.2
    detector = make_rsu_detector(s)
    boxes_tune = [detector.detect(f.rgb) for f in seq_tune.frames]
    boxes_case = [detector.detect(f.rgb) for f in seq_case.frames]
    grid = (([0.4, 0.6], [60.0], [0.0, 2.5], [3]) if quick else
            ([0.3, 0.4, 0.5, 0.6, 0.7], [50.0, 60.0, 80.0], [0.0, 2.5, 3.5], [2, 3, 4]))
    rows = []
    for score, rng, merge, hits in itertools.product(*grid):
        r = replay(seq_tune, boxes_tune, score, rng, merge, hits)
        r.update(score_threshold=score, max_range_m=rng, merge_radius_m=merge, confirm_hits=hits)
        rows.append(r)
    rows.sort(key=lambda r: (r["false_per_min"] + r["dup_per_min"], -r["coverage"], r["pos_median_m"]))
    d = Settings()
    defaults = dict(score_threshold=d.detector.score_threshold, max_range_m=d.perception.max_range_m,
                    merge_radius_m=d.perception.merge_radius_m, confirm_hits=d.tracker.confirm_hits)
    case = replay(seq_case, boxes_case, defaults["score_threshold"], defaults["max_range_m"],
                  defaults["merge_radius_m"], defaults["confirm_hits"])
    return {"selected": rows[0], "defaults": defaults, "rows": rows, "case_study_at_defaults": case}


# -- main ----------------------------------------------------------------------------------------------------
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--backends", nargs="+", default=["onnx", "torch", "classical"])
    p.add_argument("--bsms", type=int, default=1000)
    p.add_argument("--realtime-seconds", type=float, default=8.0)
    p.add_argument("--tune", action="store_true", help="also sweep the perception operating points (minutes)")
    p.add_argument("--json", type=Path, default=RESULTS / "rsu_app.json")
    p.add_argument("--quick", action="store_true")
    args = p.parse_args(argv)
    if args.quick:
        args.threads, args.backends, args.bsms, args.realtime_seconds = [1], ["onnx"], 200, 3.0
    import onnxruntime
    import torch

    report = {"machine": machine_info(torch=torch.__version__, onnxruntime=onnxruntime.__version__),
              "paper": {"stage1_ms": PAPER_STAGE1_MS, "stage2_ms": PAPER_STAGE2_MS}}
    print("rendering the case study's camera sequence ...", flush=True)
    seq = render_sequence(CASE)
    rows = []
    for backend, threads in itertools.product(args.backends, args.threads):
        if backend == "classical" and threads != args.threads[0]:
            continue  # OpenCV's threads change nothing measurable for this one
        rows.append(stage1(seq, backend, threads))
    report["stage1"] = rows
    print(f"\nStage 1: camera frame -> objects (detect + project + track), {len(seq.frames)} case-study frames "
          f"640x480")
    print(f"{'backend':<12}{'threads':>8}{'p50 ms':>10}{'p99 ms':>10}{'FPS':>8}{'x paper':>10}")
    print(f"{'seed paper (YOLOv7, 8-core CPU)':<30}{PAPER_STAGE1_MS:>10.0f}{'':>10}{1000 / PAPER_STAGE1_MS:>8.2f}"
          f"{1.0:>10.0f}")
    for r in rows:
        print(f"{r['backend']:<12}{r['threads']:>8}{r['p50_ms']:>10.1f}{r['p99_ms']:>10.1f}{r['fps_p50']:>8.1f}"
              f"{r['vs_paper']:>10.0f}")
    onnx1 = next((r for r in rows if r["backend"] == "onnx" and r["threads"] == 1), None)
    if onnx1:
        print(f"goal: stage 1 p50 <= 20 ms with onnx on 1 thread: {onnx1['p50_ms']:.1f} ms "
              f"{'PASS' if onnx1['p50_ms'] <= 20 else 'FAIL'}")
    report["stage2"] = s2 = stage2(args.bsms)
    print("\nStage 2: objects -> signed frame (build + UPER encode + 1609.2 sign, ECDSA P-256)")
    print(f"{'message':<12}{'p50 ms':>10}{'p99 ms':>10}{'x paper':>10}")
    print(f"{'seed paper':<12}{PAPER_STAGE2_MS:>10.1f}{'':>10}{1.0:>10.0f}")
    for name in ("bsm", "spat", "map"):
        r = s2[name]
        print(f"{name:<12}{r['p50_ms']:>10.3f}{r['p99_ms']:>10.3f}{r['vs_paper']:>10.1f}")
    print(f"(BSM: encode {s2['bsm']['encode_p50_ms']:.3f} ms + sign {s2['bsm']['sign_p50_ms']:.3f} ms)")
    verdict = "PASS" if s2["bsm"]["p50_ms"] <= 1 else "FAIL"
    print(f"goal: stage 2 <= 1 ms per BSM: {s2['bsm']['p50_ms']:.3f} ms {verdict}")
    if args.realtime_seconds > 0:
        print(f"\nrealtime run of the case study, {args.realtime_seconds:g} s at rtf 1 ...", flush=True)
        rt = report["realtime"] = realtime_run(args.realtime_seconds)
        if "error" in rt:
            print("realtime run failed:", rt["error"])
        else:
            print(f"camera {rt['camera_fps']:.1f} FPS offered; the app processed {rt['processed_fps']:.1f} FPS "
                  f"({rt['frames_processed']}/{rt['frames_offered']}, skipped {rt['frames_skipped']}); stage 1 "
                  f"p50/p99 {rt['stage1_compute_ms']['p50']}/{rt['stage1_compute_ms']['p99']} ms; {rt['bsms']} BSMs "
                  f"for {rt['bsm_tracks']} tracks; late slots skipped {rt['slots_skipped_late']}")
    if args.tune:
        print("\nrendering the tuning sequence and sweeping operating points ...", flush=True)
        seq_tune = render_sequence(TUNING)
        t = report["tune"] = tune(seq_tune, seq, args.quick)
        print(f"\nOperating points on {TUNING.relative_to(ROOT)} (best 10 of {len(t['rows'])})")
        head = f"{'score':>6}{'range':>7}{'merge':>7}{'hits':>5}{'false/min':>11}{'dup/min':>9}{'cover':>7}" \
               f"{'pos med':>9}{'hdg p90':>9}"
        print(head)
        for r in t["rows"][:10]:
            print(f"{r['score_threshold']:>6.2f}{r['max_range_m']:>7.0f}{r['merge_radius_m']:>7.1f}"
                  f"{r['confirm_hits']:>5}"
                  f"{r['false_per_min']:>11.1f}{r['dup_per_min']:>9.1f}{r['coverage']:>7.3f}{r['pos_median_m']:>9.2f}"
                  f"{r['hdg_p90_deg']:>9.1f}")
        print(f"selected: {({k: t['selected'][k] for k in t['defaults']})}; the app's defaults: {t['defaults']}")
        c = t["case_study_at_defaults"]
        print(f"case study at the defaults: false-track BSMs {c['false_per_min']:.1f}/min, duplicates "
              f"{c['dup_per_min']:.1f}/min, coverage {c['coverage']:.3f}, median position error "
              f"{c['pos_median_m']:.2f} m, p90 heading error {c['hdg_p90_deg']:.1f} deg")
    write_report(args.json, report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
