"""EVSP end to end, as a user runs it: `v2i run` on scenarios/evsp.toml and evsp_no_preemption.toml, the ev's OBU
app and the RSU app started by the master as processes on zenoh (loopback), in lockstep under `fixed`.
The request travels SRM (air) -> RSU (verify, arbitrate) -> AB3418 SetPreempt over the RS-232 model ->
controller -> SSM + SPaT; at 1200 baud the serial leg costs what the RS-232 model says (ANCHORS S1). The
shipped files are copied into a temporary folder (the first run makes the keys there) and each run gets a
free port."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from test_rsu_app_support import free_port, run_pairwise

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).with_name("v2i")
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")


@pytest.fixture(scope="module")
def study(tmp_path_factory, fmu_dir):
    root = tmp_path_factory.mktemp("evsp") / "scenarios"
    (root / "apps").mkdir(parents=True)
    for name in ("evsp.toml", "evsp_no_preemption.toml"):
        shutil.copy(ROOT / "scenarios" / name, root / name)
    for name in ("rsu_evsp.toml", "ev_obu.toml"):
        shutil.copy(ROOT / "scenarios" / "apps" / name, root / "apps" / name)
    return root


def run(study: Path, base: str, out: Path, baud: int | None = None, stop: float | None = None) -> dict:
    variant = study / f"run-{out.name}.toml"
    extra = f"[time]\nstop = {stop}\n" if stop else ""
    if baud:
        extra = f"""
[time]
stop = 14.0    # the serial figures are in by then (the ev's green comes at 7.5 s)
[fmus.tlc.parameters]
baud = {float(baud)}
[participants.rsu]
command = ["{{python}}", "-m", "rsu_app", "--config", "apps/rsu_evsp.toml", "--set", "spat.baud={baud}"]
"""
    variant.write_text(f"""
[scenario]
extends = "{base}"
[bridge]
listen = ["tcp/127.0.0.1:{free_port()}"]
{extra}""")
    proc = subprocess.run([str(V2I), "run", str(variant), "--out", str(out), "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return {"metrics": json.loads((out / "metrics.json").read_text()),
            "series": (out / "timeseries.csv").read_bytes(), "dir": out}


@pytest.fixture(scope="module")
def runs(study, tmp_path_factory):
    out = tmp_path_factory.mktemp("evsp-runs")
    jobs = {"evsp": ("evsp.toml", out / "evsp"), "none": ("evsp_no_preemption.toml", out / "none"),
            "1200": ("evsp.toml", out / "evsp-1200", 1200), "again": ("evsp.toml", out / "evsp-again", None, 14.0)}
    return run_pairwise(lambda job: run(study, *job), jobs)


def serial_exchange(run_dir: Path) -> list[tuple]:
    """What crossed the RS-232 model and when, in simulated time (the log's wall-clock fields left out)."""
    return [(e["t"], e["event"], e.get("hex"), e.get("wire_end"))
            for e in map(json.loads, (run_dir / "serial-tlc.jsonl").read_text().splitlines())]


def test_lockstep_under_the_fixed_policy_repeats_bit_for_bit(runs):
    """Issue 39: evsp.toml run again (side by side with other runs, so at another wall-clock pace) and
    stopped at 14 s, past the request and the ev's green, gives the first run's time series byte for byte
    up to there, the same bytes over the serial link at the same simulated times, and the same request."""
    first, again = runs["evsp"], runs["again"]
    assert len(again["series"]) > 1000 and first["series"].startswith(again["series"])
    exchange = [e for e in serial_exchange(again["dir"]) if e[0] < 13.9]  # the end of a run closes the port
    assert len(exchange) > 1000  # polled back to back all run long
    assert [e for e in serial_exchange(first["dir"]) if e[0] < 13.9] == exchange
    p, q = first["metrics"]["preemption"], again["metrics"]["preemption"]
    assert q["granted"] and {k: q[k] for k in ("srm_to_green_ms", "stages_ms", "rejected")} == \
        {k: p[k] for k in ("srm_to_green_ms", "stages_ms", "rejected")}


def test_the_ev_gets_its_green_before_it_reaches_the_stop_line(runs):
    p = runs["evsp"]["metrics"]["preemption"]
    assert p["requested"] and p["granted"] and p["signal_group"] == 8 and p["ev"] == "ev"
    # preemption entry: min(min green, 3 s) + yellow 3.3 s + red clearance 1.2 s at most, plus the request's legs
    assert 0 < p["srm_to_green_ms"] <= (3.0 + 3.3 + 1.2) * 1000 + 200
    assert p["red_violations"] == 0 and p["ev_stopped_s"] == 0.0
    assert p["ev_delay_s"] < 1.0
    s = p["stages_ms"]
    assert s["srm_air"] > 0 and s["serial_round_trip"] >= s["serial_wire"] > 0 and s["ssm"] >= 0
    assert s["serial_wire"] == pytest.approx((9 + 8) * 10 / 9600 * 1000, abs=1e-3)   # ANCHORS S1


def test_without_the_request_the_controller_keeps_its_plan_and_the_ev_meets_red(runs):
    p = runs["none"]["metrics"]["preemption"]
    assert not p["requested"] and not p["granted"] and p["srm_to_green_ms"] is None
    # its driver stops at the north-south green's red and waits for the plan's east-west green (t = 30 s)
    assert p["red_violations"] == 0 and p["ev_stopped_s"] > 10.0
    assert p["ev_delay_s"] >= runs["evsp"]["metrics"]["preemption"]["ev_delay_s"] + 2.0
    # the cross-street car keeps its green
    assert p["cross_delay_s"] is not None and p["cross_delay_s"] < 1.0


def test_cross_traffic_stops_on_the_red_the_preemption_gives_it(runs):
    """The car from the south on phase 2 (its driver looks at the head facing it) meets the preemption's
    yellow far enough out to stop, stands at its line, and goes on when the preemption exits; nobody enters
    on red in either run."""
    import csv
    import io

    p = runs["evsp"]["metrics"]["preemption"]
    assert p["red_violations"] == 0 and p["red_violators"] == []
    assert p["cross_delay_s"] > 5.0
    rows = list(csv.DictReader(io.StringIO(runs["evsp"]["series"].decode())))
    standing = [r for r in rows if float(r["car.v"]) < 0.05]
    assert standing, "the cross-street car never stopped"
    front = max(float(r["car.y"]) for r in standing) + 3.7
    assert -7.0 <= front <= -5.5  # short of its stop line (y = -5.5), not in the junction
    assert {float(r["tlc.state_2"]) for r in standing} >= {3.0}
    t_green = next(float(r["time"]) for r in rows if float(r["time"]) > float(standing[0]["time"])
                   and float(r["tlc.state_2"]) in (5.0, 6.0))
    assert float(standing[-1]["time"]) <= t_green + 0.2  # it stood for red, and went when it turned green


def test_the_serial_leg_costs_what_the_rs232_model_says(runs):
    fast, slow = runs["evsp"]["metrics"]["preemption"], runs["1200"]["metrics"]["preemption"]
    assert slow["granted"]
    wire_fast, wire_slow = fast["stages_ms"]["serial_wire"], slow["stages_ms"]["serial_wire"]
    assert wire_fast == pytest.approx((9 + 8) * 10 / 9600 * 1000, abs=1e-3)     # metrics round to 1 µs
    assert wire_slow == pytest.approx((9 + 8) * 10 / 1200 * 1000, abs=1e-3)
    # the acknowledgement comes after both frames' wire time and the controller's 10 ms turnaround (ANCHORS S7),
    # later still when a status poll was on the line ahead of it
    for p, wire in ((fast, wire_fast), (slow, wire_slow)):
        assert p["stages_ms"]["serial_round_trip"] >= wire + 10.0 - 10.0   # less one 10 ms step: tick-dated



def test_the_report_shows_the_preemption(runs):
    """report.html is not IMA-only: a preemption run's page carries its figures and a signal timeline."""
    from master.report.page import write_report

    page, _ = write_report([runs["evsp"]["dir"]])
    text = page.read_text()
    for row in ("preemption granted", "preemption srm_to_green_ms", "preemption ev_delay_s",
                "preemption red_violations", "preemption cross_delay_s", "preemption stage serial_wire"):
        assert f"<th>{row}</th>" in text, row
    assert "alt='signal timeline' src='data:image/png;base64," in text
