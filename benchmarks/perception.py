"""Benchmark: the RSU perception design space (the seed paper's Table 2, on this machine's CPU).

    python benchmarks/perception.py [--data data/heldout] [--frames 200] [--threads 1 2]
                                    [--busy 0 1] [--json PATH] [--quick]

For each backend (torch and onnx with the shipped weights, torch again with
its network through torch.compile ("torch-compiled", the detector's
`compile=True`), the classical background-subtraction baseline with each
frame's empty-scene image) and
each CPU thread count, over the first N frames of a `v2i dataset` folder
(default the held-out set, 640x480), the median time per frame of each stage:

    pre-process   resize to the network input and scale to float (learned); none (classical)
    inference     the network (torch forward / onnxruntime run); the foreground mask (classical)
    post-process  heatmap peaks -> boxes (learned); blobs -> boxes and labels (classical)
    projection    every box (score >= 0.3) to a ground point, geo.box_to_ground at the heading a
                  track supplies in steady state (here: the best-overlapping truth's heading);
                  "proj cold" (separate column): with the heading search a vehicle's first
                  frames need (no track yet)
    tracking      Tracker.update with the frame's ground points (frames are independent scenes
                  stepped at 10 Hz, so most detections open tracks: an upper bound on its cost)

Beside load (`--busy 1`, the default runs 0 and 1): the learned backends again
while one other process keeps a core busy, as the master and the renderer do
in a run on this 2-core machine; this is what chose the detectors' default of
1 thread (`rsu_app.perception.detector.DEFAULT_THREADS`): a second thread has
no free core to run on and waits for the busy one. On a machine with CUDA,
torch also runs on the GPU (rows "torch cuda"); without one the JSON says why
those rows are missing.

FPS = 1000 / (sum of the stage medians, warm projection); "cold FPS" with the cold
projection; "detector FPS" leaves out projection and tracking. AP@0.5 beside each row comes from the same run's detections (score
threshold 0.05, as `v2i eval-detector`). The reference rows are the seed
paper's (ANCHORS I6/I7): YOLOv7 at 3.6 s/frame on an 8-core CPU, 30 FPS on a
GTX 1650, 10 FPS on a Zynq 7020, and the 10 FPS the 10 Hz BSMs need; ratio =
FPS / the paper's CPU FPS. Results go to JSON (default
benchmarks/results/perception.json). `--quick`: 40 frames, 1 thread only.
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
# (with an editable install ROOT is already on the path, behind this folder)
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.common import RESULTS, machine_info, write_report  # noqa: E402
from rsu_app.perception.dataset import Dataset, load_dataset  # noqa: E402
from rsu_app.perception.detector import Detection, make_detector  # noqa: E402
from rsu_app.perception.evaluate import evaluate_detections, iou_matrix  # noqa: E402
from rsu_app.perception.geo import CameraModel, GeoError, box_to_ground  # noqa: E402
from rsu_app.perception.model import decode, preprocess  # noqa: E402
from rsu_app.perception.tracker import GroundDetection, Tracker  # noqa: E402

PAPER_CPU_S = 3.6  # ANCHORS I6: YOLOv7 on an 8-core CPU, s per frame
PAPER = [("seed paper YOLOv7, 8-core CPU", 1 / PAPER_CPU_S), ("seed paper YOLOv7, GTX 1650 GPU", 30.0),
         ("seed paper YOLOv7, Zynq 7020 FPGA", 10.0), ("requirement (10 Hz BSMs)", 10.0)]
STAGES = ("preprocess", "inference", "postprocess", "projection", "tracking", "projection_cold")
SCORE = 0.05
DEFAULT_DATA = ROOT / "data" / "heldout"
# the command that writes the default dataset (as README.md and rsu_app/perception/weights/RECIPE.md give it)
MAKE_HELDOUT = ("v2i dataset --scenario scenarios/ima_world.toml --out {out} --frames 400 --seed 1001 "
                "--variant heldout --backgrounds --jobs 2")


def _learned_stages(det, rgb):
    """(detections, [pre, inf, post] seconds) for the torch or onnx backend, stage by stage."""
    t0 = time.perf_counter()
    x, scale = preprocess(rgb, det.cfg)
    t1 = time.perf_counter()
    if det.name == "torch":
        import torch

        with torch.inference_mode():  # .cpu() waits for a GPU's work, so the time is the whole inference
            heat, size, off = (o.cpu().numpy() for o in det.net(torch.from_numpy(x).to(det.device)))
    else:
        heat, size, off = det.session.run(["heat", "size", "offset"], {"image": x})
    t2 = time.perf_counter()
    dets = [Detection((u0, v0, u1, v1), lab, sc) for u0, v0, u1, v1, lab, sc in
            decode(heat, size, off, scale, det.cfg.stride, det.cfg.classes, SCORE, det.top_k)]
    t3 = time.perf_counter()
    return dets, [t1 - t0, t2 - t1, t3 - t2]


def _classical_stages(det, rgb):
    t1 = time.perf_counter()
    mask = det.foreground(rgb)
    t2 = time.perf_counter()
    dets = det.boxes(rgb, mask)
    t3 = time.perf_counter()
    return dets, [0.0, t2 - t1, t3 - t2]


def busy_core(seconds: float) -> None:
    """Spin one core until killed or `seconds` pass (the stand-in for the master and renderer)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        pass


class BesideLoad:
    """`with BesideLoad(n):` n processes spinning a core each, bounded in time, stopped on exit."""

    def __init__(self, n: int, limit_s: float = 900.0):
        self.n, self.limit_s, self.procs = n, limit_s, []

    def __enter__(self):
        import multiprocessing as mp

        self.procs = [mp.get_context("spawn").Process(target=busy_core, args=(self.limit_s,), daemon=True)
                      for _ in range(self.n)]
        for pr in self.procs:
            pr.start()
        time.sleep(0.5 if self.procs else 0.0)
        return self

    def __exit__(self, *exc):
        for pr in self.procs:
            pr.terminate()
            pr.join(5)


def run_backend(name: str, threads: int, ds: Dataset, frames: list, operating: float = 0.3,
                device: str = "cpu", busy: int = 0) -> dict:
    cv2.setNumThreads(threads)
    if name == "classical":
        det, stages = make_detector("classical"), _classical_stages
    elif name in ("torch", "torch-compiled"):
        det = make_detector("torch", threads=threads, score_threshold=SCORE, device=device,
                            compile=name == "torch-compiled")
        stages = _learned_stages
    else:
        det, stages = make_detector(name, threads=threads, score_threshold=SCORE), _learned_stages
    tracker = Tracker()
    times = {k: [] for k in STAGES}
    all_dets = []
    for i, (s, rgb, bg) in enumerate(frames):
        if name == "classical" and bg is not None:
            det.set_background(bg)
        if i == 0:
            for _ in range(3):
                stages(det, rgb)  # warm-up
        dets, (pre, inf, post) = stages(det, rgb)
        all_dets.append(dets)
        cam = CameraModel.from_dict(s.camera)
        kept = [d for d in dets if d.score >= operating]  # what a deployed RSU would pass on
        headings = []  # the heading a track would supply: the best-overlapping truth's
        for d in kept:
            g = [t for t in s.truths if t.heading is not None]
            iou = iou_matrix([d.box], [t.box for t in g])[0] if g else []
            headings.append(g[int(np.argmax(iou))].heading if len(iou) and max(iou) > 0 else 0.0)
        t0 = time.perf_counter()
        ground = []
        for d in kept:
            try:
                gx, gy = box_to_ground(d.box, cam, d.label)
            except GeoError:
                continue
            ground.append(GroundDetection(float(gx), float(gy), d.label, d.score))
        t1 = time.perf_counter()
        tracker.update(0.1 * i, ground)
        t2 = time.perf_counter()
        for d, h in zip(kept, headings):
            try:
                box_to_ground(d.box, cam, d.label, heading=h)
            except GeoError:
                pass
        t3 = time.perf_counter()
        for k, v in zip(STAGES, (pre, inf, post, t3 - t2, t2 - t1, t1 - t0)):
            times[k].append(v * 1000)
    rep = evaluate_detections(Dataset(ds.root, [s for s, _, _ in frames], ds.categories, ds.info), all_dets, name)
    med = {k: statistics.median(v) for k, v in times.items()}
    det_ms = med["preprocess"] + med["inference"] + med["postprocess"]
    total = det_ms + med["projection"] + med["tracking"]
    cold = det_ms + med["projection_cold"] + med["tracking"]
    label = name + (" cuda" if device == "cuda" else "") + (f", {busy} busy core" if busy else "")
    return {"backend": label, "threads": threads, "device": device, "busy_cores": busy, "frames": len(frames),
            "ms_median": med,
            "detector_ms": det_ms, "total_ms": total, "detector_fps": 1000 / det_ms, "fps": 1000 / total,
            "fps_cold": 1000 / cold,
            "ratio_vs_paper_cpu": (1000 / total) / (1 / PAPER_CPU_S), "ap50": rep.ap50["overall"],
            "ap": rep.ap["overall"], "ap50_emergency": rep.ap50["emergency"], "ap50_car": rep.ap50["car"]}


def _shown(path: Path) -> str:
    """`path` as the user would type it from the repository root (relative when it is inside)."""
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA,
                    help="dataset folder of `v2i dataset` with --backgrounds (default: data/heldout in the repository)")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--backends", nargs="+", default=["torch", "torch-compiled", "onnx", "classical"],
                    choices=["torch", "torch-compiled", "onnx", "classical"])
    ap.add_argument("--json", type=Path, default=RESULTS / "perception.json")
    ap.add_argument("--busy", type=int, nargs="+", default=[0, 1],
                    help="busy cores beside the learned backends (default: 0 and 1)")
    ap.add_argument("--quick", action="store_true", help="40 frames, 1 thread, no busy core")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.threads, args.busy = min(args.frames, 40), [1], [0]
    if not (args.data / "annotations.json").is_file():
        print(f"error: no dataset in {args.data} (no annotations.json). Make it first, from the repository root:\n"
              f"  {MAKE_HELDOUT.format(out=_shown(args.data))}", file=sys.stderr)
        return 2
    import onnxruntime
    import torch

    ds = load_dataset(args.data)
    frames = [(s, s.load(), s.background()) for s in ds.samples[:args.frames]]
    info = machine_info(torch=torch.__version__, onnxruntime=onnxruntime.__version__, opencv=cv2.__version__,
                        numpy=np.__version__)
    rows = []
    runs = [(b, t, "cpu", n) for n in args.busy for t in args.threads for b in args.backends
            if n == 0 or b != "classical"]
    if "torch" in args.backends and torch.cuda.is_available():
        runs.append(("torch", 1, "cuda", 0))
        gpu = {"device": torch.cuda.get_device_name(0)}
    else:
        gpu = {"skipped": "no CUDA device on this machine (torch.cuda.is_available() is false): the torch "
                          "backend's GPU path was not measured"}
        print(f"  GPU rows: {gpu['skipped']}", file=sys.stderr)
    for b, threads, device, busy in runs:
        with BesideLoad(busy):
            r = run_backend(b, threads, ds, frames, device=device, busy=busy)
        rows.append(r)
        print(f"  {r['backend']:<22} threads {threads}: {r['fps']:.1f} FPS, AP50 {r['ap50']:.3f}", file=sys.stderr)
    hdr = (f"{'configuration':<36} {'thr':>3} {'pre':>6} {'infer':>6} {'post':>6} {'proj':>6} {'track':>6} "
           f"{'total':>7} {'FPS':>7} {'det FPS':>7} {'cold':>6} {'cldFPS':>6} {'x paper':>8} {'AP50':>6} {'AP':>6} "
           f"{'AP50ev':>6}")
    print(f"\nRSU perception on {args.data} ({len(frames)} frames 640x480, medians in ms; CPU: {info['cpu_count']} cores)")
    print(hdr)
    for r in rows:
        m = r["ms_median"]
        print(f"{r['backend']:<36} {r['threads']:>3} {m['preprocess']:>6.2f} {m['inference']:>6.2f} "
              f"{m['postprocess']:>6.2f} {m['projection']:>6.2f} {m['tracking']:>6.2f} {r['total_ms']:>7.2f} "
              f"{r['fps']:>7.1f} {r['detector_fps']:>7.1f} {m['projection_cold']:>6.1f} {r['fps_cold']:>6.1f} {r['ratio_vs_paper_cpu']:>8.0f} {r['ap50']:>6.3f} "
              f"{r['ap']:>6.3f} {r['ap50_emergency']:>6.3f}")
    for label, fps in PAPER:
        print(f"{label:<36} {'':>3} {'':>6} {1000 / fps:>6.0f} {'':>6} {'':>6} {'':>6} {1000 / fps:>7.0f} "
              f"{fps:>7.2f} {'':>7} {'':>6} {'':>6} {fps * PAPER_CPU_S:>8.1f} {'':>6} {'':>6}")
    clean = lambda x: None if isinstance(x, float) and not math.isfinite(x) else x  # noqa: E731
    write_report(args.json, {
        "benchmark": "perception", "machine": info, "data": str(args.data), "frames": len(frames),
        "gpu": gpu, "stages": list(STAGES), "rows": [{k: clean(v) for k, v in r.items()} for r in rows],
        "reference": [{"configuration": lab, "fps": fps, "ms": 1000 / fps, "ratio_vs_paper_cpu": fps * PAPER_CPU_S,
                       "source": "ANCHORS I6/I7 (seed paper Table 2, section V-B)"} for lab, fps in PAPER]})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
