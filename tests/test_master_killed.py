"""`kill -9` of the master mid-run: what it recorded stays on disk, and the apps it started do not outlive it.

The recorder flushes its rows at least every FLUSH_S (0.05 s) of wall time, so a killed run loses at most the rows
of its last 0.05 s and never leaves a torn row in the middle (README, "The run folder"). The started participants die with the master (bridges.timesync.lifeline: Linux's parent-death
signal) instead of waiting out the master's silence (`master_timeout_s`, 80 s with this scenario's heartbeat
timeout of 20 s).
"""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from bridges.timesync.bench import free_tcp_port

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")


def children(pid: int) -> list[int]:
    """Processes whose parent is `pid` (from /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(entry.name))
    return out


def alive(pid: int) -> bool:
    """Running (a zombie nobody reaped counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_kill_9_of_the_master_keeps_every_row_and_leaves_no_orphans(write_scenario, tmp_path):
    echo = json.dumps(["{python}", "-m", "bridges.timesync.echo_participant", "--delay", "0.002"])
    path = write_scenario(f"""
[scenario]
name = "killed"
[time]
stop = 60.0
step = 0.01
[fmus.car]
fmu = "{{vehicle}}"
[fmus.car.start]
accel_cmd = 1.0
[bridge]
transport = "zenoh"
prefix = "test/killed-{uuid.uuid4().hex[:8]}"
listen = ["tcp/127.0.0.1:{free_tcp_port()}"]
heartbeat_s = 0.5
heartbeat_timeout_s = 20.0
[participants.a]
role = "echo"
command = {echo}
[participants.b]
role = "echo"
command = {echo}
""")
    out = tmp_path / "run"
    master = subprocess.Popen([sys.executable, "-m", "master.cli", "run", str(path), "--out", str(out), "--quiet"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    series = out / "timeseries.csv"
    try:
        deadline = time.monotonic() + 120
        while not series.exists() or series.read_text().count("\n") < 200:
            assert master.poll() is None, master.communicate()
            assert time.monotonic() < deadline, "the run did not get going"
            time.sleep(0.1)
        apps = children(master.pid)
        assert len(apps) == 2, apps
        rows_seen = series.read_text().count("\n") - 1
        os.kill(master.pid, signal.SIGKILL)
        master.wait(timeout=10)
        killed_at = time.monotonic()
        while any(alive(p) for p in apps) and time.monotonic() - killed_at < 10:
            time.sleep(0.05)
        survivors = [p for p in apps if alive(p)]
        gone_after = time.monotonic() - killed_at
    finally:
        if master.poll() is None:
            master.kill()
            master.wait()
    for p in survivors:  # never leave them behind, even when the test fails
        os.kill(p, signal.SIGKILL)
    assert not survivors, f"participants {survivors} outlived the master by 10 s"
    assert gone_after < 5.0

    text = series.read_text()
    lines = text.split("\n")
    header, body = lines[0].split(","), lines[1:]
    complete = body if text.endswith("\n") else body[:-1]  # at most the row being written is torn
    complete = [line for line in complete if line]
    assert len(complete) >= rows_seen
    rows = list(csv.reader(complete))
    assert all(len(r) == len(header) for r in rows)
    times = [float(r[0]) for r in rows]
    assert times == sorted(times) and times[0] == 0.0
    assert all(abs(b - a - 0.01) < 1e-9 for a, b in zip(times, times[1:]))  # no row lost in between
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["status"] == "running"  # the master never got to write its end: the folder says so


def test_the_lifeline_is_armed_only_for_a_child_of_the_named_master():
    from bridges.timesync import lifeline

    assert lifeline.arm({}) is False  # not started by a master (a box on the network, a user's shell)
    assert lifeline.arm({lifeline.ENV: "not-a-pid"}) is False
    assert lifeline.arm({lifeline.ENV: str(os.getppid() + 100000)}) is False  # the parent is someone else


def test_rows_reach_the_disk_within_the_flush_interval(tmp_path):
    """What a kill can lose, on a fake clock: rows written less than FLUSH_S ago, never older ones."""
    from master.run.recorder import FLUSH_S, TIMESERIES, RunRecorder

    now = [100.0]
    rec = RunRecorder(tmp_path, ["a"], clock=lambda: now[0])
    on_disk = lambda: (tmp_path / TIMESERIES).read_text().count("\n") - 1  # noqa: E731
    rec.row(0.0, [1])
    assert on_disk() == 1  # the first row at once
    for k in range(1, 5):
        now[0] += FLUSH_S / 10
        rec.row(k * 0.01, [k])
    assert on_disk() == 1  # younger than FLUSH_S: may still be in the buffer
    now[0] += FLUSH_S
    rec.row(0.05, [5])
    assert on_disk() == 6  # the interval passed: everything so far is out
    rec.close()
