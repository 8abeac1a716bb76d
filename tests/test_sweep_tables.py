"""The sweep's outputs from its ledger, without running anything: metrics flattened into rows, the safe limit
of the summary, and the DSE table with the seed paper's rows and the editable costs."""
from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from master.sweep.runner import SweepResult, safe_limits
from master.sweep.dse import check_dse, write_dse
from master.sweep.spec import load_sweep
from master.sweep.table import columns, flatten, rows

ROOT = Path(__file__).resolve().parent.parent
TINY = ROOT / "tests" / "scenarios" / "sweep_tiny.toml"


def metrics(collision: bool, gap: float, stage1: float | None = None) -> dict:
    return {"scenario": "x", "status": "stopped" if collision else "completed", "collision": collision,
            "min_gap_m": gap, "pet_s": 0.5, "pairs": {"cav-ev": {"min_gap_m": gap}},
            "latency_ms": {"stage1": {"p50": stage1, "p99": stage1, "max": stage1, "n": 3},
                           "e2e": {"p50": 70.0, "p99": 90.0, "max": 95.0, "n": 3}},
            "pdr": {"rsu->cav": {"pdr": 0.9, "delivered": 9, "dropped": 1}}}


def test_flatten_and_rows():
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": None}) == {"a.b": 1, "a.c": "[1, 2]", "d": None}


@pytest.fixture
def radio(tmp_path):
    path = tmp_path / "radio.toml"
    path.write_text(textwrap.dedent(f"""
        [sweep]
        base = "{TINY}"
        [[sweep.axis]]
        name = "loss"
        key = "v2x.channel.loss_prob"
        values = [0.0, 0.2, 0.4]
        [[sweep.axis]]
        name = "radio"
        key = "v2x.channel.technology"
        values = ["dsrc", "cv2x"]
        [sweep.summary]
        safe_limit = "loss"
    """))
    return load_sweep(path)


def test_rows_carry_parameters_status_and_every_metric(radio):
    points = radio.points()
    latest = {points[0].id: {"status": "ok", "metrics": metrics(False, 1.2, 50.0), "wall_s": 3.0, "host": "h"},
              points[1].id: {"status": "failed", "error": "boom", "metrics": None}}
    table = rows(points, latest)
    assert table[0]["loss"] == 0.0 and table[0]["radio"] == "dsrc" and table[0]["status"] == "ok"
    assert table[0]["min_gap_m"] == 1.2 and table[0]["latency_ms.e2e.p99"] == 90.0
    assert table[0]["pdr.rsu->cav.pdr"] == 0.9 and table[0]["run_status"] == "completed"
    assert "pairs.cav-ev.min_gap_m" not in table[0]  # per-pair detail stays in the run folder
    assert table[1]["status"] == "failed" and table[1]["error"] == "boom"
    assert table[2]["status"] == "pending"
    cols = columns(table, points)
    assert cols[:6] == ["point", "folder", "loss", "radio", "status", "error"]
    assert cols.index("collision") < cols.index("latency_ms.e2e.p50") < cols.index("pdr.rsu->cav.pdr")


def test_safe_limit_is_the_largest_value_up_to_which_nothing_collided(radio):
    points = radio.points()
    outcome = {("0", "dsrc"): (False, "ok"), ("0.2", "dsrc"): (False, "ok"), ("0.4", "dsrc"): (True, "ok"),
               ("0", "cv2x"): (False, "ok"), ("0.2", "cv2x"): (None, "failed"), ("0.4", "cv2x"): (False, "ok")}
    latest = {}
    for p in points:
        collided, status = outcome[(p.labels["loss"], p.labels["radio"])]
        latest[p.id] = {"status": status, "metrics": metrics(collided, 0.0 if collided else 1.0)
                        if status == "ok" else None}
    result = SweepResult(Path("."), points, rows(points, latest))
    # dsrc: 0.2 (0.4 collides); cv2x: 0 (0.2 failed: nothing is known beyond it)
    assert safe_limits(radio, result) == {"radio=dsrc": 0.2, "radio=cv2x": 0.0}


def test_the_dse_table_has_the_papers_rows_and_the_costs(tmp_path):
    costs = tmp_path / "costs.toml"
    costs.write_text((ROOT / "scenarios" / "sweeps" / "costs.toml").read_text()
                     + '\n[platforms.mybox]\nlabel = "My box"\nkind = "measured"\ncost_usd = 1234.5\n')
    path = tmp_path / "dse.toml"
    path.write_text(textwrap.dedent(f"""
        [sweep]
        base = "{TINY}"
        [[sweep.axis]]
        name = "platform"
        key = "participants.rsu.args"
        values = [["--hardware", "cpu-i7"], ["--detector", "onnx"], ["--detector", "mybox"]]
        labels = ["cpu-i7", "onnx", "mybox"]
        [sweep.dse]
        platform = "platform"
        costs = "costs.toml"
    """))
    spec = load_sweep(path)
    assert check_dse(spec) == []
    points = spec.points()
    latest = {points[0].id: {"status": "ok", "metrics": {**metrics(True, 0.0, 3703.7), "latency_policy": "fixed"},
                             "host": "h", "cpu": "cpu X, 2 cores"},
              points[1].id: {"status": "ok", "metrics": {**metrics(False, 1.3, 12.5), "latency_policy": "measured"},
                             "host": "h", "cpu": "cpu X, 2 cores"},
              points[2].id: {"status": "failed", "error": "v2i run exited 1: lost\nmore"}}
    text = write_dse(spec, points, rows(points, latest), tmp_path).read_text()
    lines = [ln for ln in text.splitlines() if ln.startswith("| ")]
    assert lines[1] == ("| Intel i7 CPU, 8 cores | seed paper Table 2 (ANCHORS I7) | – | 0.27 | no | – | – | – | – "
                        "| 277.99 |")
    assert any(ln.startswith("| NVIDIA GTX 1650 GPU | seed paper") and ln.endswith("| 3,079.00 |") for ln in lines)
    assert any(ln.startswith("| Xilinx Zynq 7020 FPGA | seed paper") and ln.endswith("| 157.30 |") for ln in lines)
    # the sweep's rows: FPS = 1000 / stage 1 p50; the verdict; the cost of the platform (or "–")
    assert "| Intel i7 CPU, 8 cores | this sweep, emulated | fixed | 0.27 | no | 3704 / 3704 | 70 / 90 | yes " \
           "| 0 | 277.99 |" in lines
    assert "| this machine: ONNX Runtime CenterNet, 1 thread | this sweep, measured | measured | 80 | yes " \
           "| 12.5 / 12.5 | 70 / 90 | no | 1.3 | – |" in lines
    assert any(ln.startswith("| My box | this sweep, measured") and "failed: v2i run exited 1: lost" in ln
               and ln.endswith("| 1,234.50 |") for ln in lines)
    assert "Measured on: h: cpu X, 2 cores." in text


def test_dse_problems_are_named(tmp_path):
    path = tmp_path / "dse.toml"
    path.write_text(f'[sweep]\nbase = "{TINY}"\n[sweep.axes]\n"time.stop" = [1.0]\n'
                    '[sweep.dse]\nplatfrom = "stop"\ncosts = "nowhere.toml"\n')
    problems = check_dse(load_sweep(path))
    assert any(p.startswith("sweep.dse.platfrom: unknown key") for p in problems)
    assert any(p.startswith("sweep.dse.platform: expected the name of an axis (stop), got None") for p in problems)
    assert any(p.startswith("sweep.dse.costs: cannot read") for p in problems)
