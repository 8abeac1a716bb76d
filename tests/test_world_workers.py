"""Cameras and lidars taken in worker processes (master/world/sensor_worker.py), issue 41 item 1.

In lockstep the listeners get, in the same order and at the same times, the same bytes as when the
master's own scene takes the samples. In realtime the loop hands a sample time over and steps on: the
sample arrives later, stamped with the run clock's time at which it was taken, and a sensor still busy
with its previous sample drops the next. A worker that dies is named with its exit code.
"""
from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from master.scenario.loader import load_scenario
from tests.test_world_radar import FakeVehicle

pytest.importorskip("pybullet")
ROOT = Path(__file__).resolve().parent.parent


def _layout():
    """The case-study world (corner building, RSU camera 640x480 at 10 Hz, the cav's 16 x 1024 lidar)."""
    return load_scenario(ROOT / "scenarios" / "ima_world.toml").world


def _fmus():
    return {"cav": FakeVehicle(1.75, -30.0, math.pi / 2, 8.3), "ev": FakeVehicle(-40.0, -1.75, 0.0, 16.7)}


def _drive(part, fmus, steps: int, t0: float = 0.0, h: float = 0.01):
    for k in range(1, steps + 1):
        t = t0 + k * h
        fmus["cav"].values["y"] = -30.0 + 8.3 * t
        fmus["ev"].values["x"] = -40.0 + 16.7 * t
        part.after_step(k - 1, t)


def _run(workers: bool, steps: int = 25):
    from master.world.world import WorldParticipant

    fmus = _fmus()
    part = WorldParticipant(_layout(), start=0.0, workers=workers)
    got = []
    part.listeners.append(lambda kind, name, t, data: got.append((kind, name, t, data)))
    part.attach(fmus, 0.0)
    try:
        _drive(part, fmus, steps)
        meta = part.metadata()
    finally:
        part.close()
    return got, meta


def test_lockstep_samples_from_the_workers_are_the_masters_own_bit_for_bit():
    here, meta_here = _run(workers=False)
    there, meta_there = _run(workers=True)
    assert meta_here["sensor_processes"] == [] and meta_there["sensor_processes"] == ["camera", "lidar"]
    assert meta_there["renderer"] == meta_here["renderer"]
    order = [(kind, name, t) for kind, name, t, _ in here]
    assert order == [(kind, name, t) for kind, name, t, _ in there]
    # 0.00, 0.10, 0.20 s: camera then lidar at each (the radar's and GNSS's samples between, as listed)
    assert [k for k, _, _ in order if k in ("camera", "lidar")] == ["camera", "lidar"] * 3
    for (kind, _, _, a), (_, _, _, b) in zip(here, there):
        if kind == "camera":
            assert a.frame_id == b.frame_id and a.t == b.t and a.seg is None and b.seg is None
            assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.P, b.P)
        elif kind == "lidar":
            assert a.pose == b.pose and np.array_equal(a.points, b.points)
            assert np.array_equal(a.body_ids, b.body_ids) and len(a.points) > 1000
        else:
            assert a == b
    assert meta_here["lidars"]["cav"]["vehicles"] == meta_there["lidars"]["cav"]["vehicles"]
    assert meta_there["cameras"]["rsu_cam"]["frames"] == 3 and meta_there["cameras"]["rsu_cam"]["render_s"]["n"] == 3


def test_realtime_samples_arrive_after_their_time_stamped_when_taken_and_a_busy_sensor_drops():
    from master.world.world import WorldParticipant

    fmus = _fmus()
    part = WorldParticipant(_layout(), start=0.0, workers=True)
    part.realtime = True
    clock = {"now": 0.0}
    part._stamp = lambda t: clock["now"]  # the run clock: here 1000 s ahead of the step's time
    got = []
    part.listeners.append(lambda kind, name, t, data: got.append((kind, name, t, data,
                                                                  part.capture_stamp[(kind, name)], clock["now"])))
    part.attach(fmus, 0.0)
    # the samples of the start are handed out while the world opens, before the clock runs (the loop's first
    # step would otherwise wait for them, and publish the run's first frame, late)
    assert [(kind, t) for kind, _, t, *_ in got if kind in ("camera", "lidar")] == [("camera", 0.0), ("lidar", 0.0)]
    assert not any(part._in_flight.values())
    try:
        for k in range(1, 31):
            t = k * 0.01
            clock["now"] = 1000.0 + t
            fmus["ev"].values["x"] = -40.0 + 16.7 * t
            part.after_step(k - 1, t)
            if k in (1, 11):
                import time

                time.sleep(1.0)  # the worker finishes the samples of t = 0 and 0.1 s meanwhile
        dropped = dict(part.dropped)
    finally:
        part.close()
    cams = [(t, data, stamp, seen) for kind, _, t, data, stamp, seen in got if kind == "camera"]
    # the sample of t = 0 was taken at attach (the clock then read 0.0); that of 0.1 s at clock 1000.1, and
    # handed out only at a later step (here 0.11 s): after its time, never before
    assert [t for t, *_ in cams][:2] == [0.0, pytest.approx(0.1)]
    t, frame, stamp, seen = cams[1]
    assert stamp == pytest.approx(1000.1) and seen > stamp and frame.t == pytest.approx(0.1)
    # the 0.2 s sample was handed over at 0.2 s; ten steps of posing two cars take a millisecond or so, a
    # frame tens of milliseconds: at 0.3 s the camera is still busy, so that sample is dropped, and the
    # 0.2 s one is still being drawn when the run closes (dropped with the worker)
    assert [t for t, *_ in cams] == [0.0, pytest.approx(0.1)]
    assert dropped[("camera", "rsu_cam")] == 1


def test_a_worker_that_dies_is_named_with_its_exit_code():
    from master.world.world import WorldParticipant

    fmus = _fmus()
    part = WorldParticipant(_layout(), start=0.0, workers=True)
    part.attach(fmus, 0.0)
    try:
        part._workers["camera"]._proc.kill()
        part._workers["camera"]._proc.wait()
        with pytest.raises(RuntimeError, match=r"camera worker ended \(exit code -9\)"):
            _drive(part, fmus, 10)
    finally:
        part.close()


def test_renderer_and_sensor_processes_are_scenario_keys_checked_by_name(write_scenario):
    from master.errors import ScenarioError

    base = (ROOT / "scenarios" / "ima_world.toml").read_text()
    with pytest.raises(ScenarioError) as exc:
        load_scenario(write_scenario(base.replace("[world.intersection]",
                                                  "[world]\nrenderer = \"eg\"\nsensor_processes = 1\n\n"
                                                  "[world.intersection]")))
    text = str(exc.value)
    assert "world.renderer" in text and "'eg'" in text and "did you mean 'egl'" in text
    assert "world.sensor_processes" in text and "true or false" in text
    sc = load_scenario(write_scenario(base.replace("[world.intersection]",
                                                   "[world]\nrenderer = \"tiny\"\nsensor_processes = false\n\n"
                                                   "[world.intersection]")))
    assert sc.world.renderer == "tiny" and sc.world.sensor_processes is False
    assert sc.world.resolved()["renderer"] == "tiny" and "renderer" not in _layout().resolved()


def test_the_report_says_which_renderer_drew_the_cameras_and_where_the_sensors_ran():
    from master.report.page import world_sensors_line

    meta = {"world": {"renderer": "egl", "sensor_processes": ["camera", "lidar"],
                      "cameras": {"rsu_cam": {"frames": 79, "render_s": {"p50": 0.0623}, "dropped": 2}},
                      "lidars": {"cav": {"scans": 81, "scan_s": {"p50": 0.041}, "dropped": 0}}}}
    line = world_sensors_line(meta)
    assert line == ("world: renderer egl; sensors in worker processes: camera, lidar; "
                    "camera rsu_cam: 79 taken, p50 62 ms, 2 dropped; lidar cav: 81 taken, p50 41 ms")
    assert world_sensors_line({"world": {"vehicles": []}}) is None and world_sensors_line({}) is None


def test_the_camera_archive_writes_off_the_loop_in_order_and_a_failure_is_raised_at_close(tmp_path):
    """The archive's JPEG work runs on a thread of its own; every frame handed over is on disk, in order,
    when it closes, and a frame it could not write fails the close (not lost on the thread)."""
    import csv
    from types import SimpleNamespace

    from master.run.run_records import FRAMES_CSV, CameraArchive

    part = SimpleNamespace(listeners=[])
    archive = CameraArchive(part)
    archive.open(SimpleNamespace(run_dir=tmp_path))
    eye = np.eye(3)
    for i in range(5):
        frame = SimpleNamespace(frame_id=i, t=0.1 * i, rgb=np.full((48, 64, 3), 40 * i, np.uint8), P=np.ones((3, 4)),
                                K=eye, R_wc=eye, position=np.zeros(3))
        part.listeners[0]("camera", "cam", frame.t, frame)
    meta = archive.close()
    assert meta["frames"] == 5 and part.listeners == []
    rows = list(csv.DictReader(open(tmp_path / "camera" / "cam" / FRAMES_CSV)))
    assert [int(r["frame_id"]) for r in rows] == list(range(5))
    assert all((tmp_path / "camera" / "cam" / r["file"]).stat().st_size > 100 for r in rows)

    broken = CameraArchive(part)
    broken.open(SimpleNamespace(run_dir=tmp_path / "b"))
    part.listeners[0]("camera", "cam", 0.0, SimpleNamespace(frame_id=0, t=0.0, rgb=None))  # no picture
    with pytest.raises(RuntimeError, match="camera archive"):
        broken.close()


def test_a_finished_sample_is_read_whole_even_while_the_worker_is_not_scheduled():
    # The workers run under SCHED_IDLE: while the apps hold both cores a worker may not run for a while. A
    # frame sent down the socket (a megabyte, more than the socket holds) kept the master's loop waiting, once
    # it began to read, for the worker to write the rest. The arrays now wait in shared memory and the socket
    # carries a few hundred bytes: a sample the master sees ready is read whole with the worker stopped.
    import signal
    import threading

    from master.world.sensor_worker import Job, SensorWorker

    layout = _layout()
    worker = SensorWorker("camera", layout, "tiny")
    try:
        worker.wait_ready()
        poses = {"cav": (1.75, -30.0, math.pi / 2, 8.3), "ev": (-40.0, -1.75, 0.0, 16.7)}
        worker.submit(Job("camera", "rsu_cam", 0.0, poses, {}))
        first, _ = worker.result()  # the slot's shared memory is made with the first answer
        worker.submit(Job("camera", "rsu_cam", 0.1, poses, {}))
        deadline = time.monotonic() + 60
        while not worker.ready() and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(worker._proc.pid, signal.SIGSTOP)
        got = []
        reader = threading.Thread(target=lambda: got.append(worker.result()), daemon=True)
        reader.start()
        reader.join(10.0)
        os.kill(worker._proc.pid, signal.SIGCONT)
        assert got, "the master waited for a stopped worker to finish writing a sample it had been told was ready"
        frame, seconds = got[0]
        assert frame.t == 0.1 and frame.rgb.shape == (480, 640, 3) and frame.rgb.flags.writeable and seconds > 0
        assert np.array_equal(frame.rgb, first.rgb)  # the same poses drawn twice
    finally:
        worker.close()


@pytest.mark.parametrize("memfd", [True, False], ids=["memfd", "temporary-file"])
def test_a_result_area_gives_back_the_arrays_it_was_given_and_grows(monkeypatch, memfd):
    from master.world.lidar import Scan
    from master.world.sensor_worker import ResultArea, unpack

    if not memfd:  # where the C library has no memfd_create (not Linux): an unlinked temporary file
        monkeypatch.delattr(os, "memfd_create", raising=False)
    area = ResultArea()
    try:
        rng = np.random.default_rng(1)
        small = Scan(0.1, rng.normal(size=(100, 3)), rng.integers(0, 9, 100), 16384, (1.0, 2.0, 0.5))
        head, spans, made = area.pack(small)
        assert made > 0 and len(head) < 1000  # the arrays went to the area, not into the pickle
        back = unpack(area.map, head, spans)
        assert back.t == 0.1 and back.pose == small.pose and back.n_rays == 16384
        assert np.array_equal(back.points, small.points) and np.array_equal(back.body_ids, small.body_ids)
        assert back.points.flags.writeable
        assert area.pack(small)[2] == 0  # it fits: no new area, no descriptor to send
        big = Scan(0.2, rng.normal(size=(100_000, 3)), rng.integers(0, 9, 100_000), 16384)
        head, spans, made = area.pack(big)
        assert made >= big.points.nbytes + big.body_ids.nbytes  # grown for it
        assert np.array_equal(unpack(area.map, head, spans).points, big.points)
    finally:
        area.close()
