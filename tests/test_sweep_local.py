"""`v2i sweep` on the local engine, as real processes on a cheap scenario (tests/scenarios/sweep_tiny.toml,
about a second a point): the table holds one row per point with what each point's run folder says, the
plots are PNGs of the promised size, a re-run skips the finished points, and a failing point is recorded
with its error, does not stop the others, and is run again by the next invocation."""
from __future__ import annotations

import csv
import json
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).parent / "v2i"
TINY = ROOT / "tests" / "scenarios" / "sweep_tiny.toml"
PNG = b"\x89PNG\r\n\x1a\n"


def sweep(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([str(V2I), "sweep", *args], capture_output=True, text=True, timeout=timeout, cwd=ROOT)


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def ledger(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "points.jsonl").read_text().splitlines()]


@pytest.fixture
def four_points(tmp_path, fmu_dir) -> Path:
    path = tmp_path / "four.toml"
    path.write_text(textwrap.dedent(f"""
        [sweep]
        name = "four"
        base = "{TINY}"
        [[sweep.axis]]
        name = "ev_v"
        key = "fmus.ev.parameters.v0"
        values = [12.0, 16.667]
        [[sweep.axis]]
        name = "cav_v"
        key = "fmus.cav.parameters.v0"
        values = [6.0, 9.0]
        [sweep.plots]
        outcome_map = {{ x = "ev_v", y = "cav_v" }}
        curves = {{ x = "ev_v", by = "cav_v" }}
    """))
    return path


def test_a_four_point_sweep_its_table_plots_and_resume(four_points, tmp_path):
    out = tmp_path / "out"
    r = sweep(str(four_points), "--out", str(out), "--jobs", "2", "--quiet")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "4 points — 4 ok, 0 failed (4 run now, 0 finished earlier)" in r.stdout
    rows = read_csv(out / "sweep.csv")
    assert sorted((float(row["ev_v"]), float(row["cav_v"])) for row in rows) == [
        (12.0, 6.0), (12.0, 9.0), (16.667, 6.0), (16.667, 9.0)]
    for row in rows:
        assert row["status"] == "ok" and row["error"] == ""
        run = out / row["folder"]
        resolved = tomllib.loads((run / "scenario.resolved.toml").read_text())
        assert resolved["fmus"]["ev"]["parameters"]["v0"] == float(row["ev_v"])  # the point's value was run
        assert resolved["fmus"]["cav"]["parameters"]["v0"] == float(row["cav_v"])
        metrics = json.loads((run / "metrics.json").read_text())  # the row is the run's metrics.json
        assert row["collision"] == ("true" if metrics["collision"] else "false")
        assert float(row["min_gap_m"]) == pytest.approx(metrics["min_gap_m"])
        assert row["run_status"] == metrics["status"]
        if metrics["pet_s"] is not None:
            assert float(row["pet_s"]) == pytest.approx(metrics["pet_s"])
    assert {row["collision"] for row in rows} == {"true", "false"}  # the geometry gives both outcomes

    import pyarrow.parquet as pq

    table = pq.read_table(out / "sweep.parquet").to_pylist()
    assert [t["point"] for t in table] == [row["point"] for row in rows]
    assert [t["collision"] for t in table] == [row["collision"] == "true" for row in rows]

    from PIL import Image

    for name in ("outcome_map.png", "curves.png"):
        data = (out / name).read_bytes()
        assert data.startswith(PNG), name
        with Image.open(out / name) as image:
            assert image.size == (800, 500), name

    summary = json.loads((out / "summary.json").read_text())
    assert (summary["points"], summary["ok"], summary["ran"]) == (4, 4, 4)
    assert summary["collisions"] == sum(row["collision"] == "true" for row in rows)

    before = {row["folder"]: (out / row["folder"] / "metadata.json").stat().st_mtime_ns for row in rows}
    again = sweep(str(four_points), "--out", str(out), "--jobs", "2", "--quiet")
    assert again.returncode == 0, again.stdout + again.stderr
    assert "(0 run now, 4 finished earlier)" in again.stdout
    assert len(ledger(out)) == 4  # nothing ran again
    assert {f: (out / f / "metadata.json").stat().st_mtime_ns for f in before} == before
    assert read_csv(out / "sweep.csv") == rows


def test_a_failing_point_is_recorded_does_not_stop_the_sweep_and_runs_again(tmp_path, fmu_dir):
    path = tmp_path / "fails.toml"
    path.write_text(textwrap.dedent(f"""
        [sweep]
        base = "{TINY}"
        [[sweep.axis]]
        name = "ev_v"
        key = "fmus.ev.parameters.v0"
        values = [12.0, "fast", 16.667]
    """))
    out = tmp_path / "out"
    r = sweep(str(path), "--out", str(out), "--quiet")
    assert r.returncode == 1, r.stdout + r.stderr  # some point failed
    rows = {row["ev_v"]: row for row in read_csv(out / "sweep.csv")}
    assert rows["12.0"]["status"] == "ok" and rows["16.667"]["status"] == "ok"
    failed = rows["fast"]
    assert failed["status"] == "failed"
    assert "v2i run exited 2" in failed["error"]
    assert "fmus.ev.parameters.v0: expected a real value" in failed["error"]
    assert (out / failed["folder"] / "sweep-point.log").is_file()
    assert "failed: ev_v=fast" in r.stdout

    again = sweep(str(path), "--out", str(out), "--quiet")
    assert again.returncode == 1
    assert "(1 run now, 2 finished earlier)" in again.stdout  # only the failed point ran again
    attempts = [e["labels"]["ev_v"] for e in ledger(out)]
    assert sorted(attempts) == ["12", "16.667", "fast", "fast"]


def test_dry_run_lists_and_checks_every_point(four_points, tmp_path):
    r = sweep(str(four_points), "--out", str(tmp_path / "out"), "--dry-run")
    assert r.returncode == 0, r.stderr
    assert r.stdout.count(" todo ") == 4 and "4 points: 4 load, 0 do not" in r.stdout
    assert not (tmp_path / "out").exists()


def test_a_bad_sweep_file_or_base_exits_2(tmp_path, fmu_dir):
    path = tmp_path / "bad.toml"
    path.write_text(f'[sweep]\nbase = "{TINY}"\n[sweep.set]\n"time.stp" = 1.0\n[sweep.axes]\n'
                    '"fmus.ev.parameters.v0" = [12.0]\n')
    r = sweep(str(path), "--out", str(tmp_path / "out"), "--quiet")
    assert r.returncode == 2
    assert "time.stp: unknown key" in r.stderr and "did you mean 'stop'" in r.stderr
    r = sweep(str(path), "--engine", "rya")
    assert r.returncode == 2 and "unknown engine 'rya'" in r.stderr
