"""Cameras and lidars in worker processes beside the master's loop.

A camera frame cost about 110 ms of CPU (640x480, pybullet's EGL renderer on
Mesa's llvmpipe with its shadow map, 20 ms without: renderer.py; TinyRenderer
about 170 ms) and a 16 x 1024 lidar scan about 45 ms: run on the loop's
thread, one after the other, they held the case-study world to 0.45-0.6x real time while the second core waited, and in a realtime
run every sample stalled the loop for several steps. Each `SensorWorker` owns
its own copy of the scene (built from the same layout, so every body has the
same id as in the master's scene), is handed the vehicles' poses and the lamp
states of one sample time (`Job`) and answers with the `Frame` or `Scan` the
master's scene would have given: the same bytes (tests/test_world_workers.py).

Processes, not threads: pybullet holds the GIL through `getCameraImage` and
`rayTestBatch`, so a thread would not overlap the loop. A worker is a fresh
interpreter (`python -m master.world.sensor_worker`), not a fork (the master
runs the bus's threads and may hold an OpenGL context) nor a multiprocessing
spawn (which runs the caller's main script again in the child), with its
thread budget in its environment (`THREADS`) and a socket to the master.

A sample's arrays come back through shared memory, not the socket (`ResultArea`): the worker runs
under SCHED_IDLE, and a megabyte-sized frame sent down the socket left the master's loop, once
it began to read, waiting for the worker to be scheduled to write the rest (in a realtime run at
RTF 1: 5 ms or more for one frame in ten, while the two apps held both cores). Now the worker fills
the area first and then sends a few hundred bytes; the master copies the arrays out.
"""
from __future__ import annotations

import mmap
import os
import pickle
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.reduction import recv_handle, send_handle
from pathlib import Path
from typing import Any

from master.world.layout import WorldLayout

# Threads each worker may start, so that master, renderer, lidar and two apps share 2 cores without
# oversubscribing them: numpy's BLAS one thread (its idle threads spin: 3.5 % of a render's profile);
# llvmpipe two raster threads unless the user set LP_NUM_THREADS (a frame cost the same CPU either way,
# 105 ms on one thread or 62 ms of wall time on two, when EGL drew its shadow map for every frame: the
# frame arrives sooner; without the map 32-33 ms of wall time in a realtime run at RTF 1).
THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
RENDER_THREADS = "2"
# Workers run under SCHED_IDLE (else niced): in realtime the loop's step deadlines and the apps come first
# (a sample a busy worker cannot take is dropped and counted; a step that misses its deadline is not), and
# in lockstep the loop waits for them anyway. Measured at RTF 1 (case study, 2 cores, both apps): see
# docs/case-study.md "In real time".
NICE = 10
START_TIMEOUT_S = 120.0  # a busy 2-core machine builds a scene and loads EGL in a few seconds
JOB_TIMEOUT_S = 60.0
ROOT = Path(__file__).resolve().parents[2]  # the folder holding the master package


@dataclass
class Job:
    """One sample to take: the world as it is at simulation time t."""

    kind: str  # "camera" or "lidar"
    name: str  # the camera's name, or the lidar's vehicle
    t: float
    poses: dict[str, tuple[float, float, float, float]]  # vehicle -> x, y, yaw, v (rear axle)
    signals: dict[str, int]  # signal head -> MovementPhaseState shown
    segmentation: bool = False  # cameras: the body-id pass too (ground truth only)
    slot: int = 0  # the result area to answer in: the master gives one no unread answer uses


class ResultArea:
    """The worker's side of one result slot: shared memory (`_anonymous_file`) the sample's arrays go to.

    `pack` pickles the sample with its arrays out of band (pickle protocol 5), copies them into the
    area, and returns what the master needs to rebuild it: the pickle's own bytes (small), the arrays'
    (offset, length) spans, and the area's size when it was made anew for this sample (0 otherwise),
    in which case its file descriptor follows the answer on the socket.
    """

    def __init__(self):
        self.map: mmap.mmap | None = None
        self.fd: int | None = None

    def pack(self, data: Any) -> tuple[bytes, list[tuple[int, int]], int]:
        buffers: list[pickle.PickleBuffer] = []
        head = pickle.dumps(data, protocol=5, buffer_callback=buffers.append)
        raws = [b.raw() for b in buffers]
        size = sum(r.nbytes for r in raws)
        made = 0
        if self.map is None or size > len(self.map):
            # room to grow: a lidar's hit count varies (a new area's descriptor follows the answer, which the
            # master may then wait for, so areas are made seldom: at the first sample, while the world opens)
            made = max(size, 1 << 16) * 2
            self.close()
            self.fd = _anonymous_file()
            os.ftruncate(self.fd, made)
            self.map = mmap.mmap(self.fd, made)
        spans, offset = [], 0
        for r in raws:
            self.map[offset:offset + r.nbytes] = r
            spans.append((offset, r.nbytes))
            offset += r.nbytes
        return head, spans, made

    def close(self) -> None:
        if self.map is not None:
            self.map.close()
        if self.fd is not None:
            os.close(self.fd)
        self.map = self.fd = None


def _anonymous_file() -> int:
    """A file descriptor of memory no name reaches: a memfd (Linux), else an unlinked temporary file."""
    if hasattr(os, "memfd_create"):
        return os.memfd_create("v2i-sensor-result", os.MFD_CLOEXEC)
    fd, path = tempfile.mkstemp(prefix="v2i-sensor-result-")
    os.unlink(path)
    return fd


def unpack(area: mmap.mmap, head: bytes, spans: list[tuple[int, int]]) -> Any:
    """The master's side: the sample rebuilt from `ResultArea.pack`'s answer, its arrays copied out of the
    area (writable, and the slot free for the next sample)."""
    view = memoryview(area)
    try:
        return pickle.loads(head, buffers=[bytearray(view[o:o + n]) for o, n in spans])
    finally:
        view.release()


def _serve(conn, layout: WorldLayout, renderer: str | None) -> None:
    """The worker's loop: build the scene, then answer jobs in order until told to stop (None)."""
    from master.world.world import World

    try:
        world = World(layout, renderer=renderer)
    except Exception as exc:  # noqa: BLE001 - said to the master, which raises it naming the worker
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", world.scene.renderer_name, dict(world.scene.vehicle_ids)))
    areas: dict[int, ResultArea] = {}
    try:
        while True:
            try:
                job = conn.recv()
            except EOFError:
                return
            if job is None:
                return
            for name, pose in job.poses.items():
                world.pose_vehicle(name, *pose)
            for head, state in job.signals.items():
                world.set_signal(head, state)
            t0 = time.perf_counter()
            try:
                if job.kind == "camera":
                    data = world.cameras[job.name].render(job.t, segmentation=job.segmentation)
                else:
                    data = world.scan(job.name, job.t)
                seconds = time.perf_counter() - t0
                area = areas.setdefault(job.slot, ResultArea())
                pickled, spans, made = area.pack(data)
            except Exception as exc:  # noqa: BLE001
                conn.send(("error", f"{type(exc).__name__}: {exc}"))
                continue
            conn.send(("ok", pickled, spans, made, seconds))
            if made:
                send_handle(conn, area.fd, os.getppid())
    finally:
        for area in areas.values():
            area.close()
        world.close()


class SensorWorker:
    """A process with its own scene that takes `kind` samples ("camera" or "lidar") in the order asked.

    `submit` hands a job over and returns at once; `ready` says whether the oldest one is done;
    `result` waits for it: (Frame or Scan, seconds the worker spent on it).
    """

    def __init__(self, kind: str, layout: WorldLayout, renderer: str | None = None):
        self.kind = kind
        env = {**os.environ, **THREADS}
        if kind == "camera" and "LP_NUM_THREADS" not in os.environ:
            env["LP_NUM_THREADS"] = RENDER_THREADS
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
        parent, child = socket.socketpair()
        self._stderr = tempfile.TemporaryFile()
        try:
            # stdout dropped: pybullet's EGL plugin prints its GL strings there
            self._proc = subprocess.Popen([sys.executable, "-m", "master.world.sensor_worker", str(child.fileno())],
                                          pass_fds=(child.fileno(),), env=env, stdin=subprocess.DEVNULL,
                                          stdout=subprocess.DEVNULL, stderr=self._stderr)
        finally:
            child.close()
        self._conn = Connection(parent.detach())
        self._conn.send((layout, renderer if kind == "camera" else "tiny"))
        self.pending = 0
        self._slots: list[int] = []  # the result slot of each sample asked for and not yet read, in order
        self._areas: dict[int, mmap.mmap] = {}  # slot -> the worker's shared memory for it
        self.renderer_name: str | None = None
        self.vehicle_ids: dict[str, int] = {}
        self._started = False

    def wait_ready(self) -> None:
        """Wait until the worker has built its scene; raises RuntimeError with the worker's reason."""
        if self._started:
            return
        msg = self._receive(START_TIMEOUT_S, "to build its scene")
        if msg[0] != "ready":
            self.close()
            raise RuntimeError(f"{self.kind} worker: could not build the scene: {msg[1]}")
        _, self.renderer_name, self.vehicle_ids = msg
        self._started = True

    def submit(self, job: Job) -> None:
        job.slot = min(set(range(len(self._slots) + 1)) - set(self._slots))  # one no unread answer is in
        try:
            self._conn.send(job)
        except OSError:
            raise self._died("to hand it a sample") from None
        self._slots.append(job.slot)
        self.pending += 1

    def ready(self) -> bool:
        return self.pending > 0 and self._conn.poll()

    def result(self) -> tuple[Any, float]:
        msg = self._receive(JOB_TIMEOUT_S, "for a sample")
        self.pending -= 1
        slot = self._slots.pop(0)
        if msg[0] != "ok":
            raise RuntimeError(f"{self.kind} worker: {msg[1]}")
        _, head, spans, made, seconds = msg
        if made:
            try:
                fd = recv_handle(self._conn)
            except (EOFError, OSError, RuntimeError):
                raise self._died("for a sample's shared memory") from None
            try:
                old = self._areas.pop(slot, None)
                if old is not None:
                    old.close()
                self._areas[slot] = mmap.mmap(fd, made)
            finally:
                os.close(fd)
        return unpack(self._areas[slot], head, spans), seconds

    def _died(self, what: str) -> RuntimeError:
        self._stderr.seek(0)
        tail = self._stderr.read().decode(errors="replace").strip().splitlines()[-3:]
        return RuntimeError(f"{self.kind} worker ended (exit code {self._proc.poll()}) while the master waited "
                            f"{what}" + (": " + " | ".join(tail) if tail else ""))

    def _receive(self, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        while not self._conn.poll(0.5):
            if self._proc.poll() is not None:
                raise self._died(what)
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.kind} worker: no answer in {timeout:g} s while the master waited {what}")
        try:
            return self._conn.recv()
        except (EOFError, OSError, pickle.UnpicklingError):
            raise self._died(what) from None

    def close(self) -> None:
        """Stop the worker (what it has not answered is dropped)."""
        try:
            self._conn.send(None)
            deadline = time.monotonic() + 5.0
            # read what it still answers: a worker blocked writing a frame nobody reads would never see the None
            while self._proc.poll() is None and time.monotonic() < deadline:
                if self._conn.poll(0.05):
                    msg = self._conn.recv()
                    if msg[0] == "ok" and msg[3]:  # a new result area's descriptor follows it
                        os.close(recv_handle(self._conn))
        except (OSError, ValueError, EOFError, pickle.UnpicklingError):
            pass
        try:
            self._proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(5.0)
        self._conn.close()
        self._stderr.close()
        for area in self._areas.values():
            area.close()
        self._areas.clear()


def main(argv: list[str] | None = None) -> int:
    """The worker process: `python -m master.world.sensor_worker FD` (FD: its socket to the master)."""
    argv = sys.argv[1:] if argv is None else argv
    conn = Connection(int(argv[0]))
    try:  # before the renderer starts its threads: they inherit the policy
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        try:
            os.nice(NICE)
        except OSError:
            pass
    try:
        layout, renderer = conn.recv()
    except EOFError:
        return 0
    _serve(conn, layout, renderer)
    conn.close()
    # Mesa's EGL can corrupt the heap at interpreter exit once the plugin ran: leave without the teardown
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
