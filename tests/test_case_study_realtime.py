"""The case study in realtime, as in the lab: the RSU app on a "box" in a second network namespace, joined to the
master's over a veth pair; the master and the AV app in the first. Wall-clock paced, and measured on one clock.

In realtime every stamp of the latency chain is on the run clock (the master's published sim/wall mapping, which
follows the pacer's schedule): the apps stamp their work on it, and the master stamps what it hands them (camera
frames, air arrivals, applied commands) on it too. So every stage is non-negative and every camera-based record
the AV app turned into a command has an end-to-end figure. Needs root and `ip netns` (skips otherwise).

RTF 1. The camera and lidar take their samples in worker processes beside the loop (issue 41), answering
through shared memory, and the loop's thread paces at nice -10 (`[time] loop_nice`; root here, as the
namespaces need): on this 2-core machine the case study keeps its clock at RTF 1 (docs/case-study.md, "In real
time"; 3 runs of 3 per renderer, 0-4 of 1200 steps late). With the default renderer here (TinyRenderer) the
idle-priority camera worker draws only about a third of the frames asked for, so frames reach the box later
than at a lower RTF. (It ran at 0.5 before the loop's priority and the shared memory, at 0.2 before the
workers.)
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from bridges.v2x import STAGES, stage_ms
from master.run.metrics import applied_times, read_csv, with_can_applied
from test_hil_netns import MASTER_IP, netns_pair  # noqa: F401  (the two-namespace fixture)
from test_rsu_app_support import free_port, make_pki

ROOT = Path(__file__).resolve().parent.parent
RTF = 1.0
PREFIX = f"test/rt-box-{uuid.uuid4().hex[:8]}"
pytest.importorskip("zenoh")
pytest.importorskip("pybullet")


def box_variant(folder: Path, port: int, can_port: int) -> Path:
    """The shipped case study with the RSU app left to the box (no command) and the run in realtime."""
    (folder / "apps").mkdir(parents=True)
    for name in ("ima_world.toml", "ima_case_study.toml"):
        shutil.copy(ROOT / "scenarios" / name, folder / name)
    for name in ("rsu.toml", "av.toml"):
        shutil.copy(ROOT / "scenarios" / "apps" / name, folder / "apps" / name)
    study = (folder / "ima_case_study.toml").read_text()
    rsu_command = re.compile(r'^command = \[.*"rsu_app".*\]\n', re.M)
    assert len(rsu_command.findall(study)) == 1, "the shipped case study's RSU command line moved"
    (folder / "case_box.toml").write_text(rsu_command.sub("", study))
    variant = folder / "realtime_box.toml"
    variant.write_text(f"""
[scenario]
extends = "case_box.toml"
[time]
mode = "realtime"
rtf = {RTF}
[bridge]
prefix = "{PREFIX}"
listen = ["tcp/{MASTER_IP}:{port}"]
[can]
port = {can_port}
[participants.cav]
command = ["{{python}}", "-m", "av_app", "--config", "apps/av.toml", "--can-port", "{can_port}",
           "--plan-log", "{{run}}/plan-cav.jsonl"]
""")
    return variant


@pytest.fixture(scope="module")
def realtime_run(netns_pair, tmp_path_factory, fmu_dir):  # noqa: F811
    master_ns, box_ns, _ = netns_pair
    folder = tmp_path_factory.mktemp("realtime-box")
    port, can_port = free_port(), free_port()
    variant = box_variant(folder, port, can_port)
    make_pki(folder / "keys", {"rsu": "0x7f,0x82", "cav": "0x20"})  # the box needs its keys before it joins
    in_ns = lambda name: ["ip", "netns", "exec", name, sys.executable]  # noqa: E731
    out = folder / "out"
    master = subprocess.Popen(in_ns(master_ns) + ["-m", "master.cli", "run", str(variant), "--out", str(out),
                                                  "--no-report"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=folder)
    box = subprocess.Popen(in_ns(box_ns) + ["-m", "rsu_app", "--config", str(folder / "apps" / "rsu.toml"),
                                            "--pki-dir", str(folder / "keys"), "--bus", "zenoh", "--prefix",
                                            PREFIX, "--connect", f"tcp/{MASTER_IP}:{port}", "--name", "rsu"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=folder)
    try:
        master_out, _ = master.communicate(timeout=400)
        box_out, box_err = box.communicate(timeout=60)
    finally:
        for proc in (master, box):
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    assert master.returncode == 0, master_out
    assert box.returncode == 0, box_err[-3000:]
    return {"stdout": master_out, "out": out, "meta": json.loads((out / "metadata.json").read_text()),
            "metrics": json.loads((out / "metrics.json").read_text()),
            "box": json.loads(box_out.strip().splitlines()[-1])}


def test_the_rsu_on_a_box_joined_over_the_veth_link_and_the_run_is_realtime(realtime_run):
    meta, box = realtime_run["meta"], realtime_run["box"]
    rsu = meta["participants"]["members"]["rsu"]
    assert rsu["host"] and "process" not in rsu  # it joined by itself, from the other namespace
    assert box["mode"] == "realtime" and box["frames"]["processed"] > 20
    # the box charged its stages at the run's RTF, which only the master's mapping carries (with 1.0 its send
    # stamps ran ahead of the run clock)
    assert box["latency"] == {"mode": "realtime", "policy": "realtime", "rtf": RTF}
    assert realtime_run["metrics"]["time_mode"] == "realtime" and realtime_run["metrics"]["rtf"] == RTF


def test_with_the_rsu_on_a_box_the_vehicle_still_yields(realtime_run):
    m = realtime_run["metrics"]
    assert m["collision"] is False, realtime_run["stdout"]
    assert 0.3 < m["min_gap_m"] < 10.0
    assert "collision: false" in realtime_run["stdout"]


# The app whose clock stamps one end of a stage while the master's stamps the other (bridges.v2x: the master
# stamps FRAME, AIR_ARRIVAL and CAN_APPLIED; the RSU app its detector's and radio's stamps; the AV app the rest).
ACROSS = {"stage1": "rsu", "air": "rsu", "stage3": "cav"}


def clock_error_ms(meta: dict, app: str) -> float:
    """How far (simulated ms) app's run clock may sit from the master's: its offset estimate is off by at most
    half the round trip of the exchange it kept (bridges.timesync.clock). All processes here read one kernel
    clock, so the true offset is 0 and the estimate itself must lie within that bound."""
    offset = meta["participants"]["members"][app]["clock_offset"]
    assert offset is not None, (app, meta["participants"])
    half_rtt = offset["rtt_ns"] / 2
    assert abs(offset["offset_ns"]) <= half_rtt + 1, (app, offset)
    assert half_rtt <= 10e6, (app, offset)  # a bound this loose could no longer tell a mixed-up clock
    return half_rtt * RTF / 1e6


def test_every_stage_is_measured_on_one_clock(realtime_run):
    """All stamps on the run clock: no stage is negative beyond the apps' clock-sync bound, and every
    camera-based record that became a command was matched to the command's application (before, the master
    stamped its step time: 7 of 139 matched). A stage stamped by two processes is good only to the app's
    offset estimate (CI once measured the air stage at -0.23 ms: the box's estimate was that far off)."""
    out = realtime_run["out"]
    records = [json.loads(line) for line in (out / "trace.jsonl").read_text().splitlines()]
    applied = applied_times(read_csv(out / "can-applied.csv"))
    slack = {stage: clock_error_ms(realtime_run["meta"], app) for stage, app in ACROSS.items()}
    bounds = realtime_run["metrics"]["clock_bound_ms"]  # what the run reports of the same bounds
    assert {app: bounds[app] for app in ACROSS.values()} == pytest.approx(
        {app: slack[stage] for stage, app in ACROSS.items()})
    assert f"rsu ±{bounds['rsu']:.2f} ms" in realtime_run["stdout"]
    from_camera = [r for r in records if r.get("app") == "cav" and "frame" in r.get("stamps", {})]
    assert len(from_camera) > 20
    matched = 0
    for record in from_camera:
        stamps = with_can_applied(record, applied)
        for stage in STAGES:
            value = stage_ms(stamps, stage)
            assert value is None or value >= -slack.get(stage, 0.0), (stage, value, slack, record)
        matched += stage_ms(stamps, "e2e") is not None
    assert matched >= 0.9 * len(from_camera)
    e2e = realtime_run["metrics"]["latency_ms"]["e2e"]
    assert e2e["n"] == matched and e2e["p50"] > 0
    assert f"E2E latency p50 {e2e['p50']:.1f} ms" in realtime_run["stdout"]
    wall_line = f"wall clock at RTF {RTF:g}: p50 {e2e['p50'] / RTF:.1f} ms"
    # at RTF 1 the run clock is the wall clock: no second line (at any other RTF, simulated ms / RTF)
    assert (wall_line in realtime_run["stdout"]) == (RTF != 1.0), realtime_run["stdout"]


def test_a_run_that_missed_deadlines_says_so(realtime_run):
    """Warned exactly when over 1 % of steps missed their deadline or the lag's p99 passed one step
    (master/run/verdict.py). It said "when any step missed", which no run met until one missed a single
    step of 1200 (the camera and lidar now in worker processes beside the loop): by the verdict's rule
    that run kept real time."""
    from master.run.verdict import MISS_FRACTION

    meta = realtime_run["meta"]
    rt = meta["realtime"]
    warned = "WARNING: the run did not keep real time" in realtime_run["stdout"]
    kept = rt["deadline_misses"] <= MISS_FRACTION * meta["steps_done"] and rt["lag_s"]["p99"] <= meta["step_s"]
    assert warned == (not kept), (rt, realtime_run["stdout"][-2000:])
