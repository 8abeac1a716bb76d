"""`v2i sweep --engine ray` on a local Ray instance (the same sweep file and table as the local engine): a
2-point sweep, its rows, and a re-run that skips them. Skipped where Ray (the `ray` extra) is not installed."""
from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("ray") is None,
                                reason="Ray is not installed (pip install 'v2i-cosim[ray]')")

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).parent / "v2i"
TINY = ROOT / "tests" / "scenarios" / "sweep_tiny.toml"


def test_two_points_on_a_local_ray_instance_and_resume(tmp_path, fmu_dir):
    path = tmp_path / "two.toml"
    path.write_text(textwrap.dedent(f"""
        [sweep]
        name = "two"
        base = "{TINY}"
        [[sweep.axis]]
        name = "ev_v"
        key = "fmus.ev.parameters.v0"
        values = [12.0, 16.667]
    """))
    out = tmp_path / "out"
    cmd = [str(V2I), "sweep", str(path), "--engine", "ray", "--jobs", "2", "--out", str(out), "--quiet"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "engine: ray at a local Ray instance, 2 CPU(s)" in r.stdout
    with open(out / "sweep.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert sorted(float(row["ev_v"]) for row in rows) == [12.0, 16.667]
    for row in rows:
        assert row["status"] == "ok", row["error"]
        resolved = tomllib.loads((out / row["folder"] / "scenario.resolved.toml").read_text())
        assert resolved["fmus"]["ev"]["parameters"]["v0"] == float(row["ev_v"])
        metrics = json.loads((out / row["folder"] / "metrics.json").read_text())
        assert float(row["min_gap_m"]) == pytest.approx(metrics["min_gap_m"])
    entries = [json.loads(line) for line in (out / "points.jsonl").read_text().splitlines()]
    assert [e["engine"] for e in entries] == ["ray", "ray"]

    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "(0 run now, 2 finished earlier)" in again.stdout
    assert len((out / "points.jsonl").read_text().splitlines()) == 2
