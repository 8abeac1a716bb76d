"""The case study when an app dies mid-run, through `v2i run` and real app processes (lockstep, fixed policy).

* `scenarios/ima_rsu_crash.toml`: the RSU app is killed at 4.2 s, after the connected vehicle heard of the
  emergency vehicle but before its lidar can see it; the RSU is optional there, so the run goes on and says
  what happened (the README states the outcome this test holds it to).
* The AV app killed at 3 s: the CAN gateway's command timeout applies its policy (brake) and records it; the
  connected vehicle stops and the run goes on.
"""
from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from test_case_study import copy_study
from test_rsu_app_support import free_port, run_pairwise

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).with_name("v2i")
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")


@pytest.fixture(scope="module")
def study(tmp_path_factory, fmu_dir):
    return copy_study(tmp_path_factory.mktemp("faults"),
                      ("ima_world.toml", "ima_case_study.toml", "ima_rsu_crash.toml"))


def run(study: Path, base: str, name: str, extra: str = "", cav: str = "") -> dict:
    bus, can = free_port(), free_port()
    variant = study / f"{name}.toml"
    variant.write_text(f"""
[scenario]
extends = "{base}"
[bridge]
listen = ["tcp/127.0.0.1:{bus}"]
[can]
port = {can}
[participants.cav]
args = ["--can-port", "{can}"]
{cav}
""" + extra)
    out = study.parent / name
    proc = subprocess.run([str(V2I), "run", str(variant), "--out", str(out), "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    return {"stdout": proc.stdout, "dir": out, "meta": json.loads((out / "metadata.json").read_text()),
            "metrics": json.loads((out / "metrics.json").read_text()),
            "scenario_events": [e for e in events if e.get("event") == "scenario_event"]}


AV_KILLED = """
[[events]]
at = 3.0
action = "kill"
participant = "cav"
"""


@pytest.fixture(scope="module")
def runs(study):
    jobs = {"rsu": ("ima_rsu_crash.toml", "rsu-crash"),
            "av": ("ima_case_study.toml", "av-crash", AV_KILLED, "required = false")}
    return run_pairwise(lambda job: run(study, *job), jobs)


def test_the_rsu_app_killed_before_the_conflict_is_reported_and_the_run_goes_on(runs):
    r = runs["rsu"]
    (kill,) = r["scenario_events"]
    assert kill["action"] == "kill" and kill["participant"] == "rsu" and kill["t"] == pytest.approx(4.2)
    part = r["meta"]["participants"]
    assert part["members"]["rsu"]["process"]["returncode"] == -9
    assert part["members"]["rsu"]["gone"].startswith("participant 'rsu' lost: its process exited with code -9")
    assert 300 < part["members"]["rsu"]["acks"] <= 420  # it followed the run until the kill at 4.2 s, not after
    assert r["meta"]["status"] == "completed"
    # what the README says happens: the vehicle had started to yield on the RSU's warning and its own lidar
    # takes over before the conflict: no collision
    assert r["metrics"]["collision"] is False and r["metrics"]["min_gap_m"] > 0.5
    assert "collision: false" in r["stdout"]


def test_the_av_app_killed_the_gateway_brakes_and_records_it(runs):
    r = runs["av"]
    assert r["meta"]["status"] == "completed"
    assert r["meta"]["participants"]["members"]["cav"]["process"]["returncode"] == -9
    can_events = [json.loads(x) for x in (r["dir"] / "can-events.jsonl").read_text().splitlines()]
    (timeout,) = [e for e in can_events if e.get("event") == "command_timeout"]
    assert timeout["policy"] == "brake" and 3.0 < timeout["t"] <= 3.0 + 0.1 + 0.05  # command_timeout_s = 0.1
    with open(r["dir"] / "timeseries.csv") as f:
        rows = list(csv.DictReader(f))
    after = [float(row["cav.v"]) for row in rows if float(row["time"]) > timeout["t"] + 3.0]
    assert after and max(after) < 0.1  # braked to a stop, and the run went on to its end
    assert r["meta"]["sim_time_reached_s"] == pytest.approx(12.0) or r["metrics"]["collision"] is True
