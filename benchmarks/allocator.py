"""Benchmark: frame loops with glibc's malloc as it comes beside bridges.allocator.keep_freed_memory.

    python benchmarks/allocator.py [--data data/heldout] [--frames 40] [--rounds 3] [--busy 0 1]
                                   [--weights NAME=PT,ONNX ...] [--renderers tiny egl] [--json PATH] [--quick]

Each case is a fresh process (the allocator's setting is the process's and sticks), run once with
V2I_MALLOC=system (glibc's defaults: the peer) and once as the project builds it (the torch detector and the
world's camera call keep_freed_memory), the two alternating, --rounds times, beside 0 and 1 busy cores (the
master and the renderer's share of a 2-core machine):

    torch, onnx      the detector, 1 thread, the shipped weights and any given with --weights, over the first
                     N frames of a `v2i dataset` folder (default data/heldout, as benchmarks/perception.py;
                     640x480): `detect()`, pre-process, network, decode
    camera-<name>    the case-study camera's 640x480 frame on that renderer (`Camera.render`, as a sensor
                     worker draws it), N frames

Per case, the median over rounds of: ms per frame (the median frame), page faults per frame and kernel CPU ms
per frame (getrusage over the frames). Ratio: glibc's ms / kept ms, per round, its median. Results go to JSON
(default benchmarks/results/allocator.json). `--quick`: 20 frames, 2 rounds, no busy core.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks.common import RESULTS, machine_info, write_report  # noqa: E402
from bridges import allocator  # noqa: E402
from benchmarks.perception import DEFAULT_DATA, MAKE_HELDOUT, BesideLoad, _shown  # noqa: E402

MODES = {"glibc": {allocator.ENV_OPT_OUT: "system"}, "kept": {}}  # the peer, and as the detector and camera set it


def _measure(step, frames: int) -> dict:
    """`step(i)` makes frame i: 3 warm-up frames (the first build kernels and buffers), then `frames` measured:
    the median ms per frame, page faults and kernel CPU ms per frame (getrusage over them), and what the
    allocator setting did in this process."""
    import numpy as np

    for i in range(3):
        step(i)
    r0, times = resource.getrusage(resource.RUSAGE_SELF), []
    for i in range(frames):
        t0 = time.perf_counter()
        step(i)
        times.append(time.perf_counter() - t0)
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    return {"ms": float(np.median(times)) * 1000, "faults_per_frame": (r1.ru_minflt - r0.ru_minflt) / frames,
            "kernel_ms_per_frame": (r1.ru_stime - r0.ru_stime) * 1000 / frames, "allocator": allocator._applied}


def child(backend: str, weights: str | None, data: Path, frames: int) -> dict:
    """One detector case in this process, over the first `frames` frames of `data` (`detect()`)."""
    from rsu_app.perception import make_detector
    from rsu_app.perception.dataset import load_dataset

    images = [s.load() for s in load_dataset(data).samples[:frames]]
    det = make_detector(backend, threads=1, **({} if weights is None else {"weights": weights}))
    return _measure(lambda i: det.detect(images[i % len(images)]), frames)


def child_camera(renderer: str, frames: int) -> dict:
    """One camera case in this process: the case-study camera's 640x480 frame (master.world.camera.Camera.render,
    as a sensor worker draws it) on `renderer`."""
    import dataclasses

    from benchmarks.world import case_study_layout, pose_case_study
    from master.world.world import World

    layout = case_study_layout()
    with World(dataclasses.replace(layout, cameras=layout.cameras[:1]), renderer=renderer) as w:
        pose_case_study(w)
        cam = next(iter(w.cameras.values()))
        return _measure(lambda i: cam.render(), frames)


def run_case(backend: str, weights: str | None, mode: str, data: Path, frames: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in (allocator.ENV_OPT_OUT, *allocator.GLIBC_ENV)}
    env.update(MODES[mode], OMP_NUM_THREADS="1")
    cmd = [sys.executable, __file__, "--child", backend, weights or "-", str(data), str(frames)]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    if out.returncode != 0:
        raise SystemExit(f"{backend} ({mode}) failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        backend, weights, data, frames = sys.argv[2:6]
        if backend.startswith("camera-"):
            print(json.dumps(child_camera(backend.removeprefix("camera-"), int(frames))))
        else:
            print(json.dumps(child(backend, None if weights == "-" else weights, Path(data), int(frames))))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--busy", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--weights", nargs="*", default=[], metavar="NAME=PT,ONNX",
                    help="other weights beside the shipped ones: a name, the torch checkpoint and the onnx file")
    ap.add_argument("--renderers", nargs="*", default=["tiny", "egl"],
                    help="the case-study camera's frame on these renderers too (none: detectors only)")
    ap.add_argument("--json", type=Path, default=RESULTS / "allocator.json")
    ap.add_argument("--quick", action="store_true", help="20 frames, 2 rounds, no busy core")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.rounds, args.busy = 20, 2, [0]
    if not (args.data / "annotations.json").is_file():
        ap.error(f"--data {args.data}: no annotations.json there; the default set is made by\n  "
                 + MAKE_HELDOUT.format(out=_shown(args.data)))
    nets = [("shipped", None, None)]
    for spec in args.weights:
        name, _, files = spec.partition("=")
        pt, _, onnx = files.partition(",")
        missing = [f for f in (pt, onnx) if not f or not Path(f).is_file()]
        if not name or missing:
            ap.error(f"--weights {spec!r}: want NAME=PT,ONNX with both files present (missing: {missing})")
        nets.append((name, pt, onnx))
    rows = []
    print(f"allocator benchmark: {args.frames} frames of {args.data}, {args.rounds} rounds, busy {args.busy}",
          file=sys.stderr)
    cases = [(name, backend, weights) for name, pt, onnx in nets
             for backend, weights in (("torch", pt), ("onnx", onnx))]
    cases += [("world", f"camera-{r}", None) for r in args.renderers]
    for busy in args.busy:
        with BesideLoad(busy):
            for name, backend, weights in cases:
                got = {m: [] for m in MODES}
                for r in range(args.rounds):
                    for mode in (MODES if r % 2 == 0 else reversed(list(MODES))):
                        got[mode].append(run_case(backend, weights, mode, args.data, args.frames))
                ratio = statistics.median(g["ms"] / k["ms"] for g, k in zip(got["glibc"], got["kept"]))
                for mode, runs in got.items():
                    rows.append({"weights": name, "backend": backend, "busy_cores": busy, "malloc": mode,
                                 "allocator": runs[0]["allocator"],
                                 **{k: statistics.median(x[k] for x in runs)
                                    for k in ("ms", "faults_per_frame", "kernel_ms_per_frame")},
                                 "ms_rounds": [round(x["ms"], 2) for x in runs],
                                 "ratio_glibc_over_kept": ratio})
                print(f"  {name} {backend} busy {busy}: {ratio:.2f}x", file=sys.stderr)
    head = f"{'weights':10} {'case':11} {'busy':>4} {'malloc':6} {'ms/frame':>9} {'FPS':>6} " \
           f"{'faults/frame':>12} {'kernel ms':>9} {'glibc/kept':>10}"
    print(head + "\n" + "-" * len(head))
    for r in rows:
        print(f"{r['weights']:10} {r['backend']:11} {r['busy_cores']:>4} {r['malloc']:6} {r['ms']:9.1f} "
              f"{1000 / r['ms']:6.1f} {r['faults_per_frame']:12.0f} {r['kernel_ms_per_frame']:9.1f} "
              + (f"{r['ratio_glibc_over_kept']:10.2f}" if r["malloc"] == "kept" else f"{'-':>10}"))
    write_report(args.json, {"benchmark": "allocator", "machine": machine_info(), "data": str(args.data),
                             "frames": args.frames, "rounds": args.rounds, "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
