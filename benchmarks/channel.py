"""Benchmark: V2X channel delivery decisions per second (FMU and vectorised model), and PDR plot.

    python benchmarks/channel.py [--decisions 20000] [--repeats 3] [--json PATH] [--png PATH]
                                 [--fmu PATH] [--quick]

1. Delivery decisions per second for N = 1, 100 and 10 000 receivers of one
   transmitter (one decision = one packet to one receiver, with every output:
   distance, path loss, shadowing, PER, expected PDR, delivered, latency):
   * `FMU`: fmpy `FMU2Slave` loop over min(N, 100) V2XChannel instances
     (pythonfmu, in-process): per decision `setReal` (rx position) +
     `setInteger` (seq) + `doStep` + `getReal`/`getBoolean` of the outputs.
     With more receivers than instances each instance is re-pointed at its
     next receiver before each doStep (one doStep = one decision), so
     10 000 receivers cost what 10 000 instances would, without 10 000
     instantiations.
   * `model scalar`: `ChannelModel.evaluate_one` per decision (what the FMU's
     do_step runs: the FMU overhead is the difference).
   * `model vectorised`: `ChannelModel.evaluate` on all N receivers per packet.
   Two configurations: 802.11p without load, and C-V2X with the load model
   (0.1 veh/m, 10 Hz). Figures: medians over repeats (min too), and the ratio
   of each path to the FMU.
2. A PNG of PDR versus distance: 802.11p (Sepulcre et al. configuration,
   23 dBm, 6 Mb/s, 190 B, 0.06 veh/m at 10 Hz, and without load) and C-V2X
   (Gonzalez-Martin et al., 20 dBm, 4 subchannels, 0.1 veh/m at 10 Hz), each
   in line of sight and with one corner building in the way (2 walls, 10 m
   inside: 21.9 dB of Sommer et al. building loss), beside the published
   curves of tests/fixtures/anchors/pdr_vs_distance.csv; markers are per-packet
   delivery ratios drawn by the model (4000 links at independent places per
   distance), which should sit on the analytical lines.
Results go to benchmarks/results/channel.json and channel_pdr.png.
`--quick` shrinks everything to a smoke test of a few seconds.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import shutil
import statistics
import sys
import time
from collections import defaultdict
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
# (with an editable install ROOT is already on the path, behind this folder)
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

RESULTS = ROOT / "benchmarks" / "results"
# the published PDR curves behind anchors C11/C12 (docs/anchors.md), carried with the tests
ANCHORS = ROOT / "tests" / "fixtures" / "anchors" / "pdr_vs_distance.csv"
NS = (1, 100, 10_000)
MAX_INSTANCES = 100
CONFIGS = {
    "dsrc": {"technology": "dsrc"},
    "cv2x+load": {"technology": "cv2x", "density_veh_per_m": 0.1, "msg_rate_hz": 10.0},
}
OUTPUTS = ("distance_m", "path_loss_db", "rx_power_dbm", "snr_db", "per", "pdr", "latency_s")
CORNER = {"walls": 2, "inside_m": 10.0}  # the direct path cuts a corner building
SEPULCRE = dict(technology="dsrc", freq_ghz=5.89, env_height_m=0.5, tx_power_dbm=23.0, data_rate_bps=6e6,
                msg_rate_hz=10.0, load_packet_bytes=190)
GONZALEZ = dict(technology="cv2x", freq_ghz=5.91, env_height_m=0.0, tx_power_dbm=20.0, cv2x_subchannels=4,
                msg_rate_hz=10.0, load_packet_bytes=190)


def receivers(n: int, seed: int = 1) -> np.ndarray:
    """n receiver positions within 300 m of the transmitter at the origin (uniform over the disc)."""
    rng = np.random.default_rng(seed)
    r = 300.0 * np.sqrt(rng.uniform(0.0, 1.0, n))
    a = rng.uniform(0.0, 2 * np.pi, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.zeros(n)])


# -- 1. decisions per second ---------------------------------------------------------
def bench_fmu(fmu: Path, params: dict, n: int, packets: int) -> float:
    """Seconds for `packets` packets to n receivers through min(n, 100) FMU instances."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    var = {v.name: v for v in md.modelVariables}
    unzip = extract(str(fmu))
    slaves = []
    try:
        for i in range(min(n, MAX_INSTANCES)):
            s = FMU2Slave(guid=md.guid, unzipDirectory=unzip, modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName=f"link{i}")
            s.instantiate()
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
            for name, value in params.items():
                vr = [var[name].valueReference]
                if var[name].type == "String":
                    s.setString(vr, [value])
                else:
                    s.setReal(vr, [float(value)])
            s.setInteger([var["rx_id"].valueReference], [i])
            s.exitInitializationMode()
            slaves.append(s)
        rx = receivers(n)
        vr_pos = [var[k].valueReference for k in ("rx_x", "rx_y", "rx_z")]
        vr_seq = [var["seq"].valueReference]
        vr_out = [var[k].valueReference for k in OUTPUTS]
        vr_del = [var["delivered"].valueReference]
        per_slave = [(s, s.setReal, s.setInteger, s.doStep, s.getReal, s.getBoolean) for s in slaves]
        k = len(per_slave)
        delivered = 0
        t0 = time.perf_counter()
        for seq in range(packets):
            t = seq * 0.1
            for j in range(n):
                _, set_real, set_int, do_step, get_real, get_bool = per_slave[j % k]
                set_real(vr_pos, rx[j].tolist())
                set_int(vr_seq, [seq])
                do_step(t, 0.1 / max(1, n // k))  # time moves on by one slot per decision
                get_real(vr_out)
                delivered += get_bool(vr_del)[0]
        elapsed = time.perf_counter() - t0
        for s in slaves:
            s.terminate()
            s.freeInstance()
    finally:
        shutil.rmtree(unzip, ignore_errors=True)
    if delivered == 0 and n * packets >= 100:
        raise RuntimeError("no packet delivered: the benchmark is not measuring a working link")
    return elapsed


def bench_scalar(params: dict, n: int, packets: int) -> float:
    from fmus.channel.model import ChannelModel

    model = ChannelModel(**params).prepare()
    rx = [tuple(p) for p in receivers(n).tolist()]
    evaluate = model.evaluate_one
    t0 = time.perf_counter()
    for seq in range(packets):
        for j, pos in enumerate(rx):
            evaluate((0.0, 0.0, 0.0), pos, 0, 0.0, 190, seq, 0, j)
    return time.perf_counter() - t0


def bench_vector(params: dict, n: int, packets: int) -> float:
    from fmus.channel.model import ChannelModel

    model = ChannelModel(**params).prepare()
    rx = receivers(n)
    ids = np.arange(n)
    tx = np.zeros(3)
    t0 = time.perf_counter()
    for seq in range(packets):
        model.evaluate(tx, rx, 0, 0.0, 190, seq, 0, ids)
    return time.perf_counter() - t0


def packets_for(kind: str, n: int, budget: int, quick: bool) -> int:
    """Packets per case so that each case makes roughly `budget` decisions (at least 3 packets)."""
    if kind == "vector":
        budget = budget * (20 if n >= 100 else 1)  # vectorised is cheap per decision
    return max(3, min(2000 if not quick else 100, budget // n))


# -- 2. PDR plot ---------------------------------------------------------------------
def published() -> dict:
    rows = defaultdict(list)
    with ANCHORS.open() as fh:
        for r in csv.DictReader(fh):
            rows[(r["config"], r["curve"])].append((float(r["distance_m"]), float(r["pdr"])))
    return {k: np.array(sorted(v)).T for k, v in rows.items()}


def sampled_pdr(model, distances, n=4000, **obstruction):
    """Delivered fraction of n links per distance, at independent places (per-packet draws)."""
    rng = np.random.default_rng(7)
    out = []
    for d in distances:
        tx = np.column_stack([rng.uniform(-5e4, 5e4, (n, 2)), np.zeros(n)])
        a = rng.uniform(0, 2 * np.pi, n)
        rx = tx + np.column_stack([d * np.cos(a), d * np.sin(a), np.zeros(n)])
        out.append(float(model.evaluate(tx, rx, seq=int(d), rx_id=np.arange(n), **obstruction).delivered.mean()))
    return np.array(out)


def plot(png: Path, quick: bool) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fmus.channel.model import ChannelModel

    pub = published()
    d = np.arange(0.0, 501.0, 5.0)
    d_mc = np.arange(25.0, 501.0, 50.0 if quick else 25.0)
    figures = {}
    fig, axes = plt.subplots(1, 2, figsize=(13, 5), sharey=True)
    panels = [
        ("IEEE 802.11p (DSRC)", axes[0], SEPULCRE, 0.06, "PDR_0.06vehm_6Mbps_10Hz_Pt23_190Bytes", None,
         dict(loc="upper right")),
        ("LTE-V2X mode 4 (C-V2X)", axes[1], GONZALEZ, 0.1,
         "cv2x_fig_CV2XMode4_beta0.1-lambda10-Pt20-S4-B190_PDR", "analytical",
         dict(loc="lower left", bbox_to_anchor=(0.33, 0.03))),
    ]
    for title, ax, params, density, config, extra, legend in panels:
        loaded = ChannelModel(**params, density_veh_per_m=density)
        single = ChannelModel(**params)
        curves = {
            f"model, LOS, {density} veh/m": (loaded.expected_pdr(d), "C0", "-"),
            f"model, corner building, {density} veh/m": (loaded.expected_pdr(d, **CORNER), "C3", "-"),
            "model, LOS, no load": (single.expected_pdr(d), "C0", ":"),
            "model, corner building, no load": (single.expected_pdr(d, **CORNER), "C3", ":"),
        }
        for label, (y, color, style) in curves.items():
            ax.plot(d, y, color=color, linestyle=style, label=label)
        mc_los = sampled_pdr(loaded, d_mc)
        mc_bld = sampled_pdr(loaded, d_mc, **CORNER)
        ax.plot(d_mc, mc_los, "o", color="C0", ms=4, label="per-packet draws (loaded), LOS")
        ax.plot(d_mc, mc_bld, "o", color="C3", ms=4, label="per-packet draws (loaded), building")
        sim = pub[(config, "simulation")]
        ax.plot(sim[0], sim[1], "k--", lw=2, label="published simulation")
        if extra:
            ana = pub[(config, extra)]
            ax.plot(ana[0], ana[1], color="0.5", linestyle="-.", label="published analytical model")
        ax.set_title(title)
        ax.set_xlabel("distance transmitter - receiver (m)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, **legend)
        at = np.interp(sim[0], d, curves[f"model, LOS, {density} veh/m"][0])
        figures[title] = {
            "config": config,
            "max_abs_diff_vs_published_simulation": float(np.max(np.abs(at - sim[1]))),
            "cbr": float(loaded.cbr),
            "pdr_los_at": {str(int(x)): float(y) for x, y in
                           zip(d[::20], curves[f"model, LOS, {density} veh/m"][0][::20])},
            "pdr_building_at": {str(int(x)): float(y) for x, y in
                                zip(d[::20], curves[f"model, corner building, {density} veh/m"][0][::20])},
            "max_abs_diff_draws_vs_analytic": float(max(
                np.max(np.abs(mc_los - loaded.expected_pdr(d_mc))),
                np.max(np.abs(mc_bld - loaded.expected_pdr(d_mc, **CORNER))))),
        }
    axes[0].set_ylabel("packet delivery ratio")
    axes[0].set_ylim(0, 1.02)
    fig.suptitle("V2XChannel: PDR versus distance (corner building: 2 walls + 10 m inside = 21.9 dB)")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)
    return figures


# -- main ------------------------------------------------------------------------------
def machine_info() -> dict:
    import fmpy

    info = {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": sys.version.split()[0],
            "numpy": np.__version__, "fmpy": fmpy.__version__,
            "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "processor": platform.processor() or platform.machine()}
    try:
        info["loadavg_start"] = list(os.getloadavg())
    except OSError:
        pass
    return info


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--decisions", type=int, default=20000,
                    help="decisions per FMU/scalar case and repeat (default 20000; vectorised: 20x)")
    ap.add_argument("--repeats", type=int, default=3, help="repeats of every case (default 3)")
    ap.add_argument("--json", type=Path, default=RESULTS / "channel.json")
    ap.add_argument("--png", type=Path, default=RESULTS / "channel_pdr.png")
    ap.add_argument("--fmu", type=Path, default=None, help="V2XChannel.fmu (default: build it into build/fmus)")
    ap.add_argument("--quick", action="store_true", help="smoke test: 1000 decisions, 1 repeat")
    args = ap.parse_args(argv)
    if args.quick:
        args.decisions, args.repeats = 1000, 1

    if args.fmu is None:
        from fmus.builder import build_all

        (res,) = build_all(ROOT / "build" / "fmus", only=["V2XChannel"])
        args.fmu = res.path
    fmu = args.fmu.resolve()
    info = machine_info()
    print(f"V2X channel benchmark: ~{args.decisions} decisions per case, {args.repeats} repeat(s), FMU {fmu}")
    print(f"machine: {info['platform']}, {info['cpu_count']} CPUs, Python {info['python']}, "
          f"numpy {info['numpy']}, fmpy {info['fmpy']}")

    runs: dict[tuple, list[float]] = defaultdict(list)
    sizes: dict[tuple, tuple[int, int]] = {}
    benches = {"FMU": lambda p, n, k: bench_fmu(fmu, p, n, k), "model scalar": bench_scalar,
               "model vectorised": bench_vector}
    for name, params in CONFIGS.items():  # warm-up: imports, FMU extraction, tables
        bench_fmu(fmu, params, 1, 3)
        bench_vector(params, 100, 3)
    for r in range(args.repeats):
        for cfg, params in CONFIGS.items():
            for n in NS:
                for path, fn in benches.items():
                    packets = packets_for("vector" if path == "model vectorised" else "loop", n, args.decisions,
                                          args.quick)
                    elapsed = fn(params, n, packets)
                    runs[(cfg, n, path)].append(n * packets / elapsed)
                    sizes[(cfg, n, path)] = (packets, n * packets)
        print(f"  repeat {r + 1}/{args.repeats} done", flush=True)

    cases = []
    print()
    print("delivery decisions per second (one packet to one receiver, all outputs); median (min) over repeats;")
    print("ratio = median / FMU median for the same configuration and N")
    head = f"{'config':<10} {'N':>6} {'path':<17} {'decisions/s':>12} {'min':>12} {'us/decision':>12} {'ratio':>8}"
    print(head)
    print("-" * len(head))
    for cfg in CONFIGS:
        for n in NS:
            fmu_med = statistics.median(runs[(cfg, n, "FMU")])
            for path in benches:
                vals = runs[(cfg, n, path)]
                med = statistics.median(vals)
                row = {"config": cfg, "receivers": n, "path": path, "decisions_per_s": {
                    "median": med, "min": min(vals), "max": max(vals), "all": vals},
                    "us_per_decision_median": 1e6 / med, "ratio_to_fmu": med / fmu_med,
                    "packets": sizes[(cfg, n, path)][0], "decisions": sizes[(cfg, n, path)][1],
                    "instances": min(n, MAX_INSTANCES) if path == "FMU" else None}
                cases.append(row)
                print(f"{cfg:<10} {n:>6} {path:<17} {med:12.0f} {min(vals):12.0f} {1e6 / med:12.2f} "
                      f"{med / fmu_med:8.1f}")

    print()
    t0 = time.perf_counter()
    figures = plot(args.png, args.quick)
    print(f"PDR plot ({time.perf_counter() - t0:.1f} s): {args.png}")
    for title, f in figures.items():
        print(f"  {title}: {f['config']}: max |model - published simulation| "
              f"{f['max_abs_diff_vs_published_simulation']:.3f}; CBR {f['cbr']:.3f}; "
              f"per-packet draws vs analytic max |diff| {f['max_abs_diff_draws_vs_analytic']:.3f}")
        print("    PDR LOS      " + "  ".join(f"{k} m {v:.3f}" for k, v in f["pdr_los_at"].items()))
        print("    PDR building " + "  ".join(f"{k} m {v:.3f}" for k, v in f["pdr_building_at"].items()))

    try:
        info["loadavg_end"] = list(os.getloadavg())
    except OSError:
        pass
    report = {"benchmark": "channel", "machine": info,
              "settings": {"decisions": args.decisions, "repeats": args.repeats, "fmu": str(fmu),
                           "receivers": list(NS), "max_fmu_instances": MAX_INSTANCES, "configs": CONFIGS,
                           "quick": args.quick},
              "units": "delivery decisions per second (one packet to one receiver)",
              "cases": cases, "pdr_plot": {"png": str(args.png), "corner_building": CORNER, "panels": figures}}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
