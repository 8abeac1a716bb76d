"""Helpers for the RSU app's process tests: run `v2i run` with the app, listen to what it sends, score it.

A *probe* participant in the test process (its own zenoh session connected to
the master's endpoint) joins the run, acknowledges every tick and records every
frame published on `v2x/tx/*` (what the apps transmit, before the air) with its
simulation time and trace stamps, every trace record on `trace/*` (the apps'
JSON records, e.g. the RSU's "detections" of each frame), and its own welcome
(the run's epoch and origin). Because it is a participant, the master does not start before the probe
is connected, so nothing the RSU sends is missed.

Ground truth comes from the run's `timeseries.csv` (rear-axle x, y and yaw of each
vehicle), moved to the body centre with the world's `centre_offset`: J2735
positions are the vehicle's centre.
"""
from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CASE_STUDY = ROOT / "scenarios" / "ima_world.toml"
SCENARIOS = Path(__file__).resolve().parent / "scenarios"


def free_port() -> int:
    from bridges.timesync.bench import free_tcp_port

    return free_tcp_port()


def run_pairwise(run, jobs: dict) -> dict:
    """`run(job)` for every job, two at a time: a lockstep run keeps about one core busy (the master, the
    renderer and the apps take turns), so two side by side fill this 2-core machine and take the time of
    one; what a lockstep run gives does not depend on the wall-clock speed."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=2) as pool:
        futures = {key: pool.submit(run, job) for key, job in jobs.items()}
        return {key: f.result() for key, f in futures.items()}


def make_pki(directory: Path, stations: dict[str, str]) -> Path:
    """`v2i pki init` through the CLI, as a user provisions a box."""
    args = [sys.executable, "-m", "master.cli", "pki", "init", str(directory)]
    for name, psids in stations.items():
        args += ["--station", f"{name}:{psids}"]
    subprocess.run(args, check=True, capture_output=True, text=True, cwd=ROOT)
    return directory


def bridge_tables(prefix: str, port: int, latency: str = "fixed", listen_host: str = "127.0.0.1") -> str:
    return f"""
[bridge]
transport = "zenoh"
prefix = "{prefix}"
listen = ["tcp/{listen_host}:{port}"]
latency = "{latency}"
join_timeout_s = 60.0
heartbeat_s = 0.5
heartbeat_timeout_s = 20.0
"""


def probe_table(name: str = "probe", sync_every: int = 10) -> str:
    return f"""
[participants.{name}]
role = "probe"
timeout_s = 60.0
sync_every = {sync_every}
"""


def rsu_table(name: str, *args: str, latencies: str = "{ detect = 0.05, encode = 0.001, sign = 0.002 }",
              command: bool = True, sync_every: int = 1) -> str:
    argv = ", ".join(json.dumps(a) for a in ["{python}", "-m", "rsu_app", *args])
    cmd = f"command = [{argv}]\n" if command else ""
    return f"""
[participants.{name}]
role = "rsu_app"
timeout_s = 60.0
sync_every = {sync_every}
latencies = {latencies}
{cmd}"""


@dataclass
class Sent:
    key: str
    sender: str
    t_sim: float
    stamps: dict
    payload: bytes


@dataclass
class Traced:
    key: str
    sender: str
    t_sim: float
    record: dict | None  # None: the payload was not a JSON object


@dataclass
class Probe:
    """A participant in this process that records what the apps transmit."""

    prefix: str
    connect: str
    name: str = "probe"
    listen: str | None = None  # an endpoint apps on other hosts connect to (zenoh peers do not route for others)
    sent: list[Sent] = field(default_factory=list)
    traces: list[Traced] = field(default_factory=list)
    world: dict = field(default_factory=dict)
    ticks: int = 0
    error: BaseException | None = None

    def start(self) -> "Probe":
        from bridges.timesync.participant import Participant
        from bridges.transport import open_bus

        extra = {"listen": [self.listen]} if self.listen else {}
        self.bus = open_bus("zenoh", prefix=self.prefix, sender=self.name, connect=[self.connect], **extra)
        self._lock = threading.Lock()
        self._sub = self.bus.subscribe("v2x/tx/*", self._on_tx)
        self._trace_sub = self.bus.subscribe("trace/*", self._on_trace)
        self.part = Participant(self.bus, self.name, "probe")
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def publish(self, key: str, payload: bytes, t_sim: float = 0.0) -> None:
        self.bus.publish(key, payload, t_sim)

    def _on_tx(self, msg) -> None:
        with self._lock:
            self.sent.append(Sent(msg.key, msg.sender, msg.t_sim, dict(msg.stamps), bytes(msg.payload)))

    def _on_trace(self, msg) -> None:
        try:
            record = json.loads(msg.payload)
        except ValueError:
            record = None
        with self._lock:
            self.traces.append(Traced(msg.key, msg.sender, msg.t_sim, record if isinstance(record, dict) else None))

    def _run(self) -> None:
        try:
            self.part.join(timeout=120)
            self.world = self.part.world
            for tick in self.part.ticks():
                self.ticks += 1
                self.part.ack(tick)
        except BaseException as exc:  # reported by join()
            self.error = exc

    def join(self, timeout: float = 60.0) -> None:
        self._thread.join(timeout)
        if self._thread.is_alive() and self.error is None:
            self.error = TimeoutError(f"probe: the run did not end within {timeout} s")
        self.part.close()
        self._sub.close()
        self._trace_sub.close()
        self.bus.close()


def run_master(scenario: Path, out: Path, timeout: float = 600.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "master.cli", "run", str(scenario), "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=timeout, cwd=scenario.parent)


def run_with_probe(scenario_text: str, folder: Path, prefix: str, port: int, name: str = "run",
                   during=None, timeout: float = 600.0) -> tuple[subprocess.CompletedProcess, Probe, Path]:
    """Write the scenario into `folder`, run it with a probe; `during(probe)` runs in a thread once the
    probe has the welcome (to publish on the bus mid-run)."""
    path = folder / f"{name}.toml"
    path.write_text(scenario_text)
    probe = Probe(prefix, f"tcp/127.0.0.1:{port}").start()
    out = folder / f"{name}-out"
    helper = None
    if during is not None:
        def later():
            import time

            deadline = time.monotonic() + 120
            while probe.ticks < 5 and time.monotonic() < deadline and probe.error is None:
                time.sleep(0.05)
            during(probe)
        helper = threading.Thread(target=later, daemon=True)
        helper.start()
    try:
        result = run_master(path, out, timeout)
    finally:
        probe.join()
        if helper is not None:
            helper.join(30)
    return result, probe, out


def app_summary(run_dir: Path, name: str) -> dict:
    """The JSON summary line the app printed last (its log in the run folder)."""
    lines = (run_dir / f"participant-{name}.log").read_text().strip().splitlines()
    for line in reversed(lines):
        if line.startswith("{"):
            return json.loads(line)
    raise AssertionError(f"no JSON summary in participant-{name}.log:\n" + "\n".join(lines[-20:]))


# -- ground truth ----------------------------------------------------------------------------------------
class Truth:
    """Vehicle centres and headings from a run's timeseries.csv."""

    def __init__(self, run_dir: Path, scenario: Path, vehicles=("cav", "ev")):
        from master.scenario.loader import load_scenario

        sc = load_scenario(scenario)
        rows = list(csv.DictReader(open(run_dir / "timeseries.csv")))
        self.t = np.array([float(r["time"]) for r in rows])
        self.vehicles = {}
        for v in vehicles:
            p = sc.instances[v].parameters
            yaw = float(p.get("yaw0", 0.0))  # both drive straight in the case study: yaw stays yaw0
            off = sc.world.vehicles[v].centre_offset
            x = np.array([float(r[f"{v}.x"]) for r in rows]) + off * math.cos(yaw)
            y = np.array([float(r[f"{v}.y"]) for r in rows]) + off * math.sin(yaw)
            self.vehicles[v] = (x, y, yaw, sc.world.vehicles[v].kind)

    def at(self, v: str, t: float) -> tuple[float, float, float]:
        x, y, yaw, _ = self.vehicles[v]
        return float(np.interp(t, self.t, x)), float(np.interp(t, self.t, y)), yaw

    def nearest(self, x: float, y: float, t: float) -> tuple[str, float]:
        best = min(((math.hypot(x - self.at(v, t)[0], y - self.at(v, t)[1]), v) for v in self.vehicles))
        return best[1], best[0]


def bsm_time(sec_mark_ms: int, t_tx: float, epoch: float) -> float:
    """The simulation time a BSM's secMark stands for: the instant with that ms-of-minute just before t_tx."""
    unix_tx = epoch + t_tx
    minute = math.floor(unix_tx / 60.0) * 60.0
    unix = minute + sec_mark_ms / 1000.0
    if unix > unix_tx + 1e-6:
        unix -= 60.0
    return unix - epoch


@dataclass
class DecodedBsm:
    t_tx: float
    t: float           # secMark's simulation time
    id: str
    msg_count: int
    x: float
    y: float
    heading: float | None
    speed: float
    emergency: bool
    stamps: dict
    bsm: object


def decode_bsms(sent: list[Sent], station: str, world: dict, verifier=None) -> tuple[list[DecodedBsm], list]:
    """Every BSM `station` transmitted, verified (when a verifier is given) and decoded; and the rejects."""
    from bridges.geo import GeoOrigin
    from bridges.j2735 import default_codec
    from bridges.j2735.bsm import Bsm
    from bridges.security import open_unsecured, time64_us
    from bridges.v2x import tx_key

    origin, epoch = GeoOrigin.from_dict(world["origin"]), float(world["epoch_unix_s"])
    out, rejects = [], []
    for s in sent:
        if s.key != tx_key(station):
            continue
        try:
            payload = verifier.verify(s.payload, time64_us(epoch + s.t_sim)).payload if verifier else \
                open_unsecured(s.payload)
        except Exception as exc:
            rejects.append((s.t_sim, repr(exc)))
            continue
        if default_codec().decode(payload).message_id != 20:
            continue
        b = Bsm.decode(payload)
        x, y, _ = origin.to_local(b.latitude, b.longitude, b.elevation)
        out.append(DecodedBsm(s.t_sim, bsm_time(b.sec_mark_ms, s.t_sim, epoch), b.temporary_id.hex(), b.msg_count,
                              float(x), float(y), b.heading, b.speed, b.emergency is not None, s.stamps, b))
    return out, rejects


def heading_error(bsm_heading_deg: float, yaw_rad: float) -> float:
    """Degrees between a J2735 heading (clockwise from north) and a world yaw (CCW from east)."""
    truth = (90.0 - math.degrees(yaw_rad)) % 360.0
    return abs((bsm_heading_deg - truth + 180.0) % 360.0 - 180.0)


def test_bsm_time_recovers_the_simulation_time_of_a_sec_mark():
    epoch = 1_700_000_123.456
    for t in (0.0, 0.05, 3.3, 59.999, 61.2):
        unix = epoch + t
        sec_mark = int(math.floor(unix * 1000 + 1e-6)) % 60000
        assert abs(bsm_time(sec_mark, t + 0.003, epoch) - t) < 1e-3


def test_heading_error_compares_compass_and_world_angles():
    assert heading_error(0.0, math.pi / 2) == 0.0          # north
    assert heading_error(90.0, 0.0) == 0.0                 # east
    assert abs(heading_error(359.0, math.pi / 2) - 1.0) < 1e-9
    assert abs(heading_error(180.0, 0.0) - 90.0) < 1e-9


# -- a probe as its own process (a network namespace the test process is not in) -----------------------------
def main(argv=None) -> int:
    """python tests/test_rsu_app_support.py probe --prefix P --connect E --out FILE: record, then write JSON."""
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("command", choices=["probe"])
    p.add_argument("--prefix", required=True)
    p.add_argument("--connect", required=True)
    p.add_argument("--name", default="probe")
    p.add_argument("--listen")
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    probe = Probe(args.prefix, args.connect, args.name, args.listen).start()
    probe.join(timeout=600)
    Path(args.out).write_text(json.dumps({
        "world": probe.world, "error": repr(probe.error) if probe.error else None, "ticks": probe.ticks,
        "sent": [{"key": s.key, "sender": s.sender, "t_sim": s.t_sim, "stamps": s.stamps, "payload": s.payload.hex()}
                 for s in probe.sent]}))
    return 0


def load_probe_record(path: Path) -> tuple[list[Sent], dict]:
    data = json.loads(Path(path).read_text())
    return [Sent(s["key"], s["sender"], s["t_sim"], s["stamps"], bytes.fromhex(s["payload"])) for s in data["sent"]], \
        data["world"]


if __name__ == "__main__":
    sys.exit(main())

