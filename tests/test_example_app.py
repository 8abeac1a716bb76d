"""The guide's minimal app (examples/hello_app.py, docs/writing-an-app.md) as a user runs it: `v2i run` on
examples/hello.toml starts two of them as processes on zenoh (loopback), in lockstep, one per vehicle.

Each broadcasts a signed BSM of its vehicle once a second and hears the other's: every BSM sent reaches the
other app, verifies and decodes to where the vehicle was (within the GNSS noise), and becomes a trace record
with its stamps (the run's metrics read the air's latency from them). Garbage on the air, injected as if the
ev sent it, is refused and counted by reason, never a crash. Two runs under the `fixed` policy trace the same
records bit for bit. The shipped scenario is copied into a temporary folder with a free port, so the first run
makes its keys there and nothing is written into the checkout.
"""
from __future__ import annotations

import csv
import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from test_rsu_app_support import free_port

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).with_name("v2i")
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")

STOP_S, RATE_HZ, SEND_LATENCY_S = 4.0, 1.0, 0.002  # examples/hello.toml
GNSS_SIGMA_M = 0.5  # examples/hello.toml: sigma_h per axis
GARBAGE_AT_S = 1.5


def run_hello(folder: Path, out: Path) -> dict:
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / "examples" / "hello.toml", folder / "hello.toml")
    variant = folder / f"{out.name}.toml"
    variant.write_text(f"""
[scenario]
extends = "hello.toml"
[bridge]
listen = ["tcp/127.0.0.1:{free_port()}"]
[[events]]
at = {GARBAGE_AT_S}
action = "inject_v2x"
station = "ev"
hex = "deadbeef00"
""")
    proc = subprocess.run([str(V2I), "run", str(variant), "--out", str(out), "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summaries = {}
    for name in ("cav", "ev"):
        log = (out / f"participant-{name}.log").read_text().strip().splitlines()
        summaries[name] = json.loads(log[-1])
    with open(out / "timeseries.csv") as f:
        rows = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(f)]
    return {"meta": json.loads((out / "metadata.json").read_text()),
            "metrics": json.loads((out / "metrics.json").read_text()),
            "trace": [json.loads(line) for line in (out / "trace.jsonl").read_text().splitlines()],
            "trace_lines": sorted((out / "trace.jsonl").read_text().splitlines()),
            "summaries": summaries, "rows": rows}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, fmu_dir):
    folder, out = tmp_path_factory.mktemp("hello-study"), tmp_path_factory.mktemp("hello-runs")
    return [run_hello(folder, out / "first"), run_hello(folder, out / "second")]


def position(rows, vehicle: str, t: float) -> tuple[float, float]:
    row = min(rows, key=lambda r: abs(r["time"] - t))
    return row[f"{vehicle}.x"], row[f"{vehicle}.y"]


def test_both_apps_joined_followed_every_tick_and_exited_cleanly(runs):
    run = runs[0]
    assert run["meta"]["status"] == "completed"
    ticks = round(STOP_S / run["meta"]["step_s"])
    for name, summary in run["summaries"].items():
        member = run["meta"]["participants"]["members"][name]
        assert member["joined"] and member["process"]["returncode"] == 0, member
        assert summary["mode"] == "lockstep" and summary["ticks"] == member["acks"] == ticks
        assert summary["sent"] == math.ceil(STOP_S * RATE_HZ), summary


def test_every_bsm_sent_is_heard_verified_and_decoded_by_the_other(runs):
    cav, ev = runs[0]["summaries"]["cav"], runs[0]["summaries"]["ev"]
    assert cav["heard"] == {"ev": ev["sent"]} and ev["heard"] == {"cav": cav["sent"]}
    assert ev["obu"]["rejected"] == {}
    assert cav["obu"]["rejected"] == {"malformed": 1}  # the injected garbage, refused and counted
    assert runs[0]["metrics"]["v2x_rejected"] == {"cav": {"malformed": 1}, "ev": {}}


def test_the_trace_records_say_where_each_vehicle_was_and_when_each_stage_happened(runs):
    run = runs[0]
    records = [r for r in run["trace"] if r.get("app") == "hello"]
    assert sorted(r["from"] for r in records) == ["cav"] * 4 + ["ev"] * 4
    for r in records:
        s = r["stamps"]
        t_send = s["send"] / 1e9
        assert abs(t_send - round(t_send) - SEND_LATENCY_S) < 1e-6  # on the 1 Hz grid + the fixed latency
        assert s["send"] < s["air_arrival"] <= s["receive"]
        x, y = position(run["rows"], r["from"], t_send)
        assert math.hypot(r["x"] - x, r["y"] - y) < 5 * GNSS_SIGMA_M, (r, x, y)
    air = run["metrics"]["latency_ms"]["air"]
    assert air["n"] == len(records) and 0 < air["max"] < 100


def test_the_fixed_policy_repeats_the_trace_bit_for_bit(runs):
    assert runs[0]["trace_lines"] == runs[1]["trace_lines"]
