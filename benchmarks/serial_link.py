"""Benchmark: simulated vs theoretical RS-232 transfer time through the built TrafficLightController FMU.

    python benchmarks/serial_link.py [--sizes 1 64 1024 4096] [--bauds 9600 19200 115200]
        [--step 1e-4] [--repeats 3] [--json PATH] [--fmu PATH] [--quick]

1. Transfer: for each size N and baud (8N1), one FMU instance (fmpy FMU2Slave, stepped at --step)
   gets N bytes in `serial_rx_hex` at t = 0 (HDLC idle flags 0x7E, which the controller's
   deframer ignores) and runs until `serial_rx_bytes` == N. Figures:
   * theoretical: N * 10 / baud (ANCHORS S1, S2);
   * simulated: the FMU's `serial_rx_end_time`, the instant the last stop bit arrived;
   * seen at: the first communication point at which all N bytes were in (resolution --step);
   * wall: wall-clock seconds of the stepping loop (median over --repeats);
   * the seed paper's measured 1024-byte RS-232 transfer, 1064.3 ms (ANCHORS S3), beside 1024 B at 9600.
2. Round trip: a GetLongStatus8 poll (8 B) and its answer (40 B) at each baud: simulated
   `serial_tx_end_time - t0` vs (8 + 40) * 10 / baud + turnaround 10 ms (ANCHORS S7).

Writes benchmarks/results/serial_link.json. `--quick`: sizes 1, 64, 1024, step 1 ms, 1 repeat.
"""
from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the repository first, and not this folder: its bridges.py would shadow the bridges package
# (with an editable install ROOT is already on the path, behind this folder)
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks.common import RESULTS, summary, write_report  # noqa: E402
from benchmarks.common import machine_info as common_machine_info  # noqa: E402

DEFAULT_JSON = RESULTS / "serial_link.json"
PAPER_1024_AT_9600_MS = 1064.3  # ANCHORS S3, seed paper section III-C
TURNAROUND = 0.010


class Fmu:
    """One TrafficLightController instance driven through FMU2Slave."""

    def __init__(self, fmu: Path, baud: float):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        md = read_model_description(str(fmu))
        self.dir = extract(str(fmu))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.s = FMU2Slave(guid=md.guid, unzipDirectory=self.dir, modelIdentifier=md.coSimulation.modelIdentifier,
                           instanceName="bench")
        self.s.instantiate()
        self.s.setupExperiment(startTime=0.0)
        self.s.setReal([self.vr["baud"], self.vr["turnaround"]], [float(baud), TURNAROUND])
        self.s.enterInitializationMode()
        self.s.exitInitializationMode()

    def close(self) -> None:
        self.s.terminate()
        self.s.freeInstance()
        shutil.rmtree(self.dir, ignore_errors=True)


def transfer(fmu: Path, n: int, baud: float, step: float) -> dict:
    f = Fmu(fmu, baud)
    s, vr = f.s, f.vr
    try:
        s.setString([vr["serial_rx_hex"]], [("7e" * n)])
        k, got = 0, 0
        limit = round((n * 12 / baud + 1.0) / step)
        w0 = time.perf_counter()
        while got < n and k < limit:
            s.doStep(k * step, step)
            k += 1
            got = s.getInteger([vr["serial_rx_bytes"]])[0]
        wall = time.perf_counter() - w0
        end = s.getReal([vr["serial_rx_end_time"]])[0]
        errors = sum(s.getInteger([vr[name] for name in ("err_garbage", "err_fcs", "err_truncated", "err_oversize")]))
    finally:
        f.close()
    if got < n:
        raise RuntimeError(f"{n} B at {baud:g} baud: only {got} bytes arrived")
    return {"simulated_s": end, "seen_at_s": k * step, "steps": k, "wall_s": wall, "decoder_errors": errors}


def round_trip(fmu: Path, baud: float, step: float) -> dict:
    from bridges import ab3418

    f = Fmu(fmu, baud)
    s, vr = f.s, f.vr
    try:
        t0, k, out = 0.5, round(0.5 / step), b""
        s.setString([vr["serial_rx_hex"]], [ab3418.request(ab3418.GET_LONG_STATUS8).hex()])
        while len(out) < 40 and k * step < 2.0:
            s.doStep(k * step, step)
            k += 1
            out += bytes.fromhex(s.getString([vr["serial_tx_hex"]])[0].decode())
        end = s.getReal([vr["serial_tx_end_time"]])[0]
    finally:
        f.close()
    return {"answer_bytes": len(out), "simulated_s": end - t0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024, 4096], help="bytes per transfer")
    ap.add_argument("--bauds", type=float, nargs="+", default=[9600, 19200, 115200], help="line speeds, bit/s")
    ap.add_argument("--step", type=float, default=1e-4, help="communication step, s (default 1e-4)")
    ap.add_argument("--repeats", type=int, default=3, help="repeats of each transfer for the wall time (default 3)")
    ap.add_argument("--json", type=Path, default=DEFAULT_JSON, help=f"result file (default {DEFAULT_JSON.relative_to(ROOT)})")
    ap.add_argument("--fmu", type=Path, default=None, help="TrafficLightController.fmu (default: build it into build/fmus)")
    ap.add_argument("--quick", action="store_true", help="smoke test: sizes 1 64 1024, step 1 ms, 1 repeat")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.step, args.repeats = [1, 64, 1024], 1e-3, 1
    if args.step <= 0 or args.repeats < 1 or min(args.sizes) < 1 or min(args.bauds) <= 0:
        ap.error("--step, --bauds must be > 0, --sizes and --repeats >= 1")
    if args.fmu is None:
        from fmus.builder import build_all

        (built,) = build_all(ROOT / "build" / "fmus", only=["TrafficLightController"])
        fmu = built.path
    else:
        fmu = args.fmu.resolve()
    import fmpy

    info = common_machine_info(fmpy=fmpy.__version__)
    print(f"serial link benchmark: 8N1, step {args.step:g} s, {args.repeats} repeat(s), FMU {fmu}")
    print(f"machine: {info['platform']}, {info['cpu_count']} CPUs, Python {info['python']}, fmpy {info['fmpy']}")

    rows = []
    header = (f"{'bytes':>6} {'baud':>7} {'theoretical ms':>15} {'simulated ms':>13} {'sim - theory':>13} "
              f"{'seen at ms':>11} {'wall s':>8} {'paper (S3) ms':>14}")
    print("\n" + header + "\n" + "-" * len(header))
    for baud in args.bauds:
        for n in args.sizes:
            results = [transfer(fmu, n, baud, args.step) for _ in range(args.repeats)]
            first = results[0]
            if any(r["simulated_s"] != first["simulated_s"] for r in results):
                raise RuntimeError("the simulated time differs between repeats")
            theory = n * 10 / baud
            paper = PAPER_1024_AT_9600_MS if (n == 1024 and baud == 9600) else None
            row = {"bytes": n, "baud": baud, "theoretical_s": theory, "simulated_s": first["simulated_s"],
                   "error_s": first["simulated_s"] - theory, "seen_at_s": first["seen_at_s"],
                   "steps": first["steps"], "decoder_errors": first["decoder_errors"],
                   "wall_s": summary([r["wall_s"] for r in results]),
                   "paper_ms": paper}
            rows.append(row)
            print(f"{n:>6} {baud:>7g} {theory * 1e3:>15.4f} {first['simulated_s'] * 1e3:>13.4f} "
                  f"{(first['simulated_s'] - theory) * 1e3:>+13.2e} {first['seen_at_s'] * 1e3:>11.2f} "
                  f"{statistics.median(r['wall_s'] for r in results):>8.3f} "
                  f"{'' if paper is None else f'{paper:.1f}':>14}")
    print("\n'seen at': first communication point with all bytes received (resolution = the step).")
    theory_ms = 1024 * 10 / 9600 * 1e3
    print(f"S3: 1024 B at 9600 8N1 is {theory_ms:.2f} ms, {(theory_ms - PAPER_1024_AT_9600_MS) / PAPER_1024_AT_9600_MS:+.2%} "
          f"from the paper's measured {PAPER_1024_AT_9600_MS} ms; on Gigabit Ethernet 1024 B is 8.72 us of wire "
          "time (the paper's ~1 ms there is software latency).")

    trips = []
    header = f"{'baud':>7} {'answer B':>9} {'theoretical ms':>15} {'simulated ms':>13} {'sim - theory':>13}"
    print("\nGetLongStatus8 round trip (8 B poll + 40 B answer + 10 ms turnaround, ANCHORS S7)")
    print(header + "\n" + "-" * len(header))
    for baud in args.bauds:
        r = round_trip(fmu, baud, args.step)
        theory = (8 + r["answer_bytes"]) * 10 / baud + TURNAROUND
        trips.append({"baud": baud, **r, "theoretical_s": theory, "error_s": r["simulated_s"] - theory})
        print(f"{baud:>7g} {r['answer_bytes']:>9} {theory * 1e3:>15.4f} {r['simulated_s'] * 1e3:>13.4f} "
              f"{(r['simulated_s'] - theory) * 1e3:>+13.2e}")

    write_report(args.json, {"benchmark": "serial_link", "framing": "8N1", "step_s": args.step,
                             "repeats": args.repeats, "fmu": str(fmu), "machine": info,
                             "transfers": rows, "round_trips": trips,
                             "paper_1024_at_9600_ms": PAPER_1024_AT_9600_MS})
    return 0


if __name__ == "__main__":
    sys.exit(main())
