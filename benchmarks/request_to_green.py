"""Benchmark: EVSP's request-to-green chain beside the IMA chain, stage by stage, from real runs.

    python benchmarks/request_to_green.py [--repeats 3] [--bauds 1200,9600,115200] [--json PATH]

Both applications run end to end as a user runs them (`v2i run`, the apps as
processes on zenoh, lockstep), one run at a time: the `measured` policy
charges each stage its real compute, so a second run beside it would charge
it that run's load too:

* EVSP (scenarios/evsp.toml, to t = 14 s: the ev's green comes at 7.5 s)
  under the `measured` latency policy (the RSU app's real compute is charged
  in simulated time), `repeats` times at 9600 baud, and once per other baud
  rate: metrics.json's preemption.stages_ms - srm_air (the SRM on the air),
  rsu (arrival -> the preemption call: verify, arbitrate), serial_round_trip
  (the call -> the controller's acknowledgement, tick-dated), serial_wire (the
  SetPreempt and its acknowledgement on the RS-232 line, bytes x 10 / baud:
  ANCHORS S1), controller (acknowledgement -> green: the NEMA clearance),
  ssm (green -> the RSU's `granted`) - and srm_to_green_ms;
* IMA (scenarios/ima_case_study.toml) under `measured`, once: latency_ms's
  stage1 (camera frame -> objects), stage2 (objects -> signed BSM), air,
  stage3 (BSM -> the cav's plan) and e2e, as p50 / p99 over the run's records.

The two chains are different in kind: IMA's is compute and air (tens of ms),
EVSP's is dominated by the controller's own clearance (seconds: minimum green,
yellow, red clearance), with the serial link the part a slow line can add.
Prints the tables and writes JSON (default benchmarks/results/request_to_green.json).
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:] = [str(ROOT)] + [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]

from benchmarks.common import RESULTS, machine_info, summary, write_report  # noqa: E402

DEFAULT_JSON = RESULTS / "request_to_green.json"
EVSP_STAGES = ("srm_air", "rsu", "serial_round_trip", "serial_wire", "controller", "ssm")
IMA_STAGES = ("stage1", "stage2", "air", "stage3", "e2e")
BASE_PORT = 47700


def run(scenario: str, out: Path, port: int, sets: list[str]) -> dict:
    """One `v2i run` (its own port); its metrics.json. A failed run stops the benchmark naming it."""
    args = [sys.executable, "-m", "master.cli", "run", str(ROOT / scenario), "--out", str(out), "--quiet",
            "--no-report", "--set", "bridge.latency=measured", "--set", f'bridge.listen=["tcp/127.0.0.1:{port}"]']
    for s in sets:
        args += ["--set", s]
    proc = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=900)
    if proc.returncode != 0:
        raise SystemExit(f"{scenario} {sets}: v2i run exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    return json.loads((out / "metrics.json").read_text())


def evsp_sets(baud: int) -> list[str]:
    return ["time.stop=14.0", f"fmus.tlc.parameters.baud={float(baud)}",
            f'participants.rsu.command=["{{python}}", "-m", "rsu_app", "--config", "apps/rsu_evsp.toml", '
            f'"--set", "spat.baud={baud}"]']


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="EVSP runs at 9600 baud")
    p.add_argument("--bauds", default="1200,9600,115200", help="baud rates, comma-separated (9600 is repeated)")
    p.add_argument("--json", type=Path, default=DEFAULT_JSON)
    args = p.parse_args(argv)
    bauds = [int(b) for b in args.bauds.split(",") if b.strip()]
    jobs = [("ima", 0, "scenarios/ima_case_study.toml", ["record.camera=false"])]
    jobs += [(f"evsp-9600-{r}", 9600, "scenarios/evsp.toml", evsp_sets(9600)) for r in range(args.repeats)]
    jobs += [(f"evsp-{b}", b, "scenarios/evsp.toml", evsp_sets(b)) for b in bauds if b != 9600]
    report = {"machine": machine_info(), "latency_policy": "measured", "repeats": args.repeats, "runs": {}}
    with tempfile.TemporaryDirectory(prefix="r2g-") as tmp:
        metrics = {name: run(scen, Path(tmp) / name, BASE_PORT + i, sets)
                   for i, (name, _, scen, sets) in enumerate(jobs)}
    for name, m in metrics.items():
        report["runs"][name] = {"preemption": m.get("preemption"), "latency_ms": m.get("latency_ms"),
                                "collision": m.get("collision")}

    ima = metrics["ima"]["latency_ms"]
    print("IMA chain (ima_case_study, measured) | p50 ms | p99 ms")
    print("--- | --- | ---")
    for st in IMA_STAGES:
        print(f"{st} | {ima[st]['p50']:.1f} | {ima[st]['p99']:.1f}")

    reps = [metrics[f"evsp-9600-{r}"]["preemption"] for r in range(args.repeats)]
    if not all(r and r["granted"] for r in reps):
        raise SystemExit("an EVSP run at 9600 baud was not granted: " + json.dumps(reps)[:2000])
    med = {st: summary([r["stages_ms"][st] for r in reps]) for st in EVSP_STAGES}
    med["srm_to_green"] = summary([r["srm_to_green_ms"] for r in reps])
    report["evsp_9600"] = med
    print(f"\nEVSP chain (evsp.toml, measured, 9600 baud, {args.repeats} runs) | median ms | min | max")
    print("--- | --- | --- | ---")
    for st, s in med.items():
        print(f"{st} | {s['median']:.1f} | {s['min']:.1f} | {s['max']:.1f}")

    print("\nbaud | serial_wire ms | serial_round_trip ms | srm_to_green ms | ev_delay_s")
    print("--- | --- | --- | --- | ---")
    by_baud = {}
    for b in sorted(set(bauds) | {9600}):
        pre = [metrics[f"evsp-9600-{r}"]["preemption"] for r in range(args.repeats)] if b == 9600 \
            else [metrics[f"evsp-{b}"]["preemption"]]
        row = {"serial_wire": statistics.median(x["stages_ms"]["serial_wire"] for x in pre),
               "serial_round_trip": statistics.median(x["stages_ms"]["serial_round_trip"] for x in pre),
               "srm_to_green": statistics.median(x["srm_to_green_ms"] for x in pre),
               "ev_delay_s": statistics.median(x["ev_delay_s"] for x in pre)}
        by_baud[str(b)] = row
        print(f"{b} | {row['serial_wire']:.1f} | {row['serial_round_trip']:.1f} | {row['srm_to_green']:.0f} | "
              f"{row['ev_delay_s']:.2f}")
    report["by_baud"] = by_baud
    write_report(args.json, report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
