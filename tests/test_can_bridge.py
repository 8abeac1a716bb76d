"""The master's CAN bridge driving a real VehicleDynamics FMU: when commands are applied, what the
status frames carry, the timeout policy, bad frames, [can] validation, and udp_multicast across processes."""
from __future__ import annotations

import csv
import json
import os
import random
import socket
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import can
import pytest
from fmpy import extract

from bridges.can.bus import open_bus
from bridges.can.codec import CavCodec, CavCommand, Mode, RollingCounter
from master.links.can_bridge import CanBridge, parse_can
from master.errors import ScenarioError
from master.fmi.runtime import FmuInstance
from master.hooks import Member, RunContext
from master.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent
H = 0.01
FLAT = {"cd_a": 0.0, "c_rr": 0.0}  # no road load: the FMU's `a` equals the applied command
CODEC = CavCodec()

SCENARIO = """
connections = ["cav.a -> other.accel_cmd"]
[time]
stop = 1.0
step = 0.01
[fmus.cav]
fmu = "{vehicle}"
parameters = { cd_a = 0.0, c_rr = 0.0, v0 = 10.0 }
[fmus.other]
fmu = "{vehicle}"
"""


@pytest.fixture
def scenario(write_scenario):
    return load_scenario(write_scenario(SCENARIO))


def parse(table, sc):
    return parse_can(table, sc.instances, connections=sc.connections, step=sc.time.step, path=sc.path)


_channels = iter(range(10_000))


def channel() -> str:
    """A fresh virtual bus per test (virtual buses with one name are shared in the process)."""
    return f"can-bridge-test-{os.getpid()}-{next(_channels)}"


class Vehicle:
    """A built VehicleDynamics FMU stepped the way master/run/cosim.py steps it, with the bridge's hooks."""

    def __init__(self, fmu_path: Path, tmp: Path, **start):
        from fmpy import read_model_description

        self._dir = extract(str(fmu_path), unzipdir=str(tmp / "unzipped"))
        self.fmu = FmuInstance("cav", read_model_description(str(fmu_path)), self._dir)
        self.fmu.instantiate(0.0, 10.0, {**FLAT, "v0": 10.0, **start})
        self.fmu.exit_initialization()
        self.rows: list[tuple[float, float, float]] = []  # (t, v, a) after each step

    def run(self, bridge: CanBridge, n: int, k0: int = 0, between=None) -> None:
        for k in range(k0, k0 + n):
            t = k * H
            bridge.before_step(k, t)
            self.fmu.do_step(t, H)
            out = self.fmu.get_by_name(["v", "a"])
            self.rows.append((round(t + H, 9), out["v"], out["a"]))
            bridge.after_step(k, t + H)
            if between is not None:
                between(k, t + H)

    def a_after(self, t_end: float) -> float:
        return next(a for t, _, a in self.rows if abs(t - t_end) < 1e-9)

    def close(self):
        self.fmu.close()


def run_context(vehicle: Vehicle, run_dir: Path) -> RunContext:
    """What the master's loop hands its hooks: here the one vehicle, stepped from 0 with step H."""
    time_settings = SimpleNamespace(start=0.0, step=H, n_steps=100, mode="lockstep", rtf=1.0)
    return RunContext(SimpleNamespace(time=time_settings), run_dir, {"cav": Member(vehicle.fmu, 1)})


def open_bridge(scenario, vehicle, run_dir: Path, **table) -> CanBridge:
    cfg = parse({"vehicle": "cav", "interface": "virtual", "channel": channel(), **table}, scenario)
    bridge = CanBridge(cfg, "lockstep")
    run_dir.mkdir(exist_ok=True)
    bridge.open(run_context(vehicle, run_dir))
    return bridge


def applied_rows(run_dir: Path) -> list[dict]:
    with open(run_dir / "can-applied.csv") as f:
        return list(csv.DictReader(f))


def command(accel, counter, echo=0, steer=0.0, mode=Mode.AUTO) -> can.Message:
    data = CODEC.encode_command(CavCommand(accel, steer, mode, False, echo, counter))
    return can.Message(arbitration_id=CODEC.command_id, data=data, is_extended_id=False)


# -- applied exactly at the step it arrived before ------------------------------------------------
def test_free_command_sent_before_step_k_is_applied_at_step_k(scenario, vehicle_fmu, tmp_path):
    veh = Vehicle(vehicle_fmu, tmp_path)
    bridge = open_bridge(scenario, veh, tmp_path / "run", sync="free", status_rate_hz=10.0,
                         command_timeout_s=10.0)
    app = open_bus(interface="virtual", channel=bridge.config.bus.channel)
    try:
        veh.run(bridge, 7)  # steps 0..6: no command, the baseline (accel_cmd = 0)
        app.send(command(2.0, counter=1))
        assert bridge.wait_received(1, 5.0)
        veh.run(bridge, 5, k0=7)  # step 7 starts at 0.07 with the command
        app.send(command(-3.0, counter=2, mode=Mode.EMERGENCY_STOP))
        assert bridge.wait_received(2, 5.0)
        veh.run(bridge, 3, k0=12)
    finally:
        app.shutdown()
        stats = bridge.close()
        veh.close()
    assert veh.a_after(0.07) == 0.0
    assert veh.a_after(0.08) == pytest.approx(2.0)  # the step [0.07, 0.08) ran with the command
    assert veh.a_after(0.12) == pytest.approx(2.0)
    assert veh.a_after(0.13) == pytest.approx(-8.0)  # EMERGENCY_STOP: estop_accel, not the -3 requested
    rows = applied_rows(tmp_path / "run")
    assert [(r["t"], r["event"], r["mode"], r["accel_cmd"]) for r in rows] == [
        ("0.0", "initial", "MANUAL", "0.0"), ("0.07", "command", "AUTO", "2.0"),
        ("0.12", "command", "EMERGENCY_STOP", "-8.0")]
    assert (stats["commands_received"], stats["commands_applied"], stats["rejected_total"]) == (2, 2, 0)


def test_drain_reads_the_bus_at_the_step_point_without_a_thread_race(scenario, vehicle_fmu, tmp_path):
    """sync = drain: a command on the bus when before_step(k) runs is applied at k, with no waiting at all."""
    veh = Vehicle(vehicle_fmu, tmp_path)
    bridge = open_bridge(scenario, veh, tmp_path / "run", sync="drain", command_timeout_s=10.0)
    app = open_bus(interface="virtual", channel=bridge.config.bus.channel)
    assert bridge._thread is None
    sent = iter(range(1, 100))

    def send_after(k, t_end):  # the app answers right after each step, before the next one starts
        app.send(command(0.1 * (k + 1), counter=next(sent)))

    try:
        veh.run(bridge, 20, between=send_after)
    finally:
        app.shutdown()
        stats = bridge.close()
        veh.close()
    assert veh.a_after(0.01) == 0.0
    for k in range(1, 20):  # the command sent after step k-1 drives step k
        assert veh.a_after(round((k + 1) * H, 9)) == pytest.approx(0.1 * k), k
    assert (stats["commands_received"], stats["commands_applied"]) == (19, 19)  # the 20th: still on the bus


# -- echo: t + one step, whatever the app's speed --------------------------------------------------
class EchoApp(threading.Thread):
    """An AV app: one command per AV_Status, echoing its Counter, after a random wall-clock delay."""

    def __init__(self, channel: str, max_delay: float, seed: int):
        super().__init__(daemon=True)
        self.bus = open_bus(interface="virtual", channel=channel)
        self.max_delay, self.rng = max_delay, random.Random(seed)
        self.stop = threading.Event()
        self.counter = RollingCounter()
        self.statuses: list[tuple[int, float]] = []  # (status Counter, speed)

    def run(self):
        while not self.stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is None or msg.arbitration_id != CODEC.status_id:
                continue
            st = CODEC.decode_message(msg)
            self.statuses.append((st.counter, st.speed))
            time.sleep(self.rng.uniform(0.0, self.max_delay))
            accel = 1.0 + (st.counter % 5) * 0.5  # a different request per status: order errors show
            self.bus.send(command(accel, self.counter.next(), echo=st.counter, steer=0.01 * (st.counter % 3)))

    def close(self):
        self.stop.set()
        self.join(5)
        self.bus.shutdown()


def echo_run(scenario, vehicle_fmu, tmp: Path, max_delay: float, seed: int):
    veh = Vehicle(vehicle_fmu, tmp)
    cfg = parse({"vehicle": "cav", "interface": "virtual", "channel": channel(), "status_rate_hz": 50.0,
                 "connect_timeout_s": 5.0}, scenario)
    app = EchoApp(cfg.bus.channel, max_delay, seed)
    app.start()
    bridge = CanBridge(cfg, "lockstep")
    (tmp / "run").mkdir()
    try:
        bridge.open(run_context(veh, tmp / "run"))
        veh.run(bridge, 40)
    finally:
        stats = bridge.close()
        app.close()
        veh.close()
    return veh.rows, applied_rows(tmp / "run"), stats, app.statuses


def test_echo_applies_the_answer_to_status_t_at_t_plus_one_step_deterministically(scenario, vehicle_fmu,
                                                                                    tmp_path):
    fast = echo_run(scenario, vehicle_fmu, tmp_path / "fast", 0.0, 1)
    slow = echo_run(scenario, vehicle_fmu, tmp_path / "slow", 0.004, 2)
    rows, applied, stats, statuses = fast
    # statuses at 0.00 (open), 0.02, ..., 0.40: 21 frames, every one answered and applied at t_s + h
    assert stats["status_sent"] == 21 and stats["status_every_steps"] == 2
    commands = [r for r in applied if r["event"] == "command"]
    assert len(commands) == 20  # the answer to the status of 0.40 would apply at 0.41, after the run
    for r in commands:
        assert float(r["t"]) == pytest.approx(float(r["basis_t"]) + H, abs=1e-12)
        assert float(r["accel_cmd"]) == 1.0 + (int(r["status_echo"]) % 5) * 0.5
    assert stats["actuation_age_s"]["min"] == pytest.approx(H) and stats["actuation_age_s"]["max"] == pytest.approx(H)
    assert stats["sync_timeouts"] == 0 and stats["commands_applied"] == 20
    # the vehicle's acceleration follows: status k (t = 0.02 k) answered with 1 + (k % 5) / 2 over [0.02k+h, ...)
    a_at = dict((t, a) for t, _, a in rows)  # a over the step that ends at t
    assert a_at[0.01] == 0.0  # [0, 0.01): the baseline, although the app answered status 0 at once
    assert a_at[0.02] == a_at[0.03] == pytest.approx(1.0)  # [0.01, 0.03): the answer to status 0 (1.0)
    assert a_at[0.04] == a_at[0.05] == pytest.approx(1.5)  # [0.03, 0.05): the answer to status 1 (t = 0.02)
    # bit-for-bit the same run when the app answers slower (and at random pace)
    assert slow[0] == rows
    strip = [{k: v for k, v in r.items() if k != "rx_time"} for r in applied]
    assert [{k: v for k, v in r.items() if k != "rx_time"} for r in slow[1]] == strip
    # the app saw the FMU's speed in each status (v0 = 10, then accelerating)
    speeds = dict(statuses)
    assert speeds[0] == pytest.approx(10.0, abs=0.005)
    v_at = dict((t, v) for t, v, _ in rows)
    assert speeds[20] == pytest.approx(v_at[0.40], abs=0.005)


# -- status frames ------------------------------------------------------------------------------
def test_status_frames_at_the_configured_rate_with_the_fmu_speed(scenario, vehicle_fmu, tmp_path):
    veh = Vehicle(vehicle_fmu, tmp_path, accel_cmd=1.0)
    ch = channel()
    listener = open_bus(interface="virtual", channel=ch)  # before open(): it sends the status of t = 0
    bridge = open_bridge(scenario, veh, tmp_path / "run", status_rate_hz=20.0, sync="free", channel=ch)
    try:
        veh.run(bridge, 50)
        frames = []
        while (msg := listener.recv(0.2)) is not None:
            frames.append(msg)
    finally:
        listener.shutdown()
        stats = bridge.close()
        veh.close()
    status = [CODEC.decode_message(m) for m in frames if m.arbitration_id == CODEC.status_id]
    assert len(status) == stats["status_sent"] == 11  # t = 0, 0.05, ..., 0.50 (every 5 steps)
    assert [s.counter for s in status] == list(range(11))
    v_at = {round(t, 2): v for t, v, _ in veh.rows}
    v_at[0.0] = 10.0
    for i, s in enumerate(status):
        assert s.speed == pytest.approx(v_at[round(0.05 * i, 2)], abs=0.005)  # resolution 0.01 m/s
        assert s.mode is Mode.MANUAL
    assert status[-1].accel == pytest.approx(1.0, abs=0.005)
    assert status[-1].speed == pytest.approx(10.5, abs=0.005)


# -- timeout policy ----------------------------------------------------------------------------------
@pytest.mark.parametrize("policy, expected", [("brake", -4.0), ("zero_accel", 0.0), ("hold", 2.0),
                                              ("manual", 0.5)])
def test_command_timeout_policy(scenario, vehicle_fmu, tmp_path, policy, expected):
    veh = Vehicle(vehicle_fmu, tmp_path, accel_cmd=0.5)  # 0.5: the baseline ("manual") input
    bridge = open_bridge(scenario, veh, tmp_path / "run", sync="free", command_timeout_s=0.05, on_timeout=policy)
    app = open_bus(interface="virtual", channel=bridge.config.bus.channel)
    try:
        app.send(command(2.0, counter=1))
        assert bridge.wait_received(1, 5.0)
        veh.run(bridge, 10)  # applied at 0.0; silent since: fallback from 0.05
        app.send(command(1.0, counter=2))
        assert bridge.wait_received(2, 5.0)
        veh.run(bridge, 2, k0=10)
    finally:
        app.shutdown()
        stats = bridge.close()
        veh.close()
    assert veh.a_after(0.05) == pytest.approx(2.0)
    assert veh.a_after(0.06) == pytest.approx(expected)  # the step from 0.05 runs the fallback
    assert veh.a_after(0.11) == pytest.approx(1.0)  # a new command ends it
    assert stats["timeouts"] == 1 and stats["fallback_s"] == pytest.approx(0.05)
    assert [r["event"] for r in applied_rows(tmp_path / "run")] == ["initial", "command", "fallback", "command"]


# -- bad frames -----------------------------------------------------------------------------------
def test_garbage_frames_are_counted_logged_and_never_applied(scenario, vehicle_fmu, tmp_path):
    veh = Vehicle(vehicle_fmu, tmp_path)
    bridge = open_bridge(scenario, veh, tmp_path / "run", sync="free")
    app = open_bus(interface="virtual", channel=bridge.config.bus.channel)
    good = command(3.0, counter=9)
    corrupt = bytearray(good.data)
    corrupt[0] ^= 0xFF
    garbage = [
        can.Message(arbitration_id=CODEC.command_id, data=bytes(corrupt), is_extended_id=False),  # checksum
        can.Message(arbitration_id=CODEC.command_id, data=bytes(good.data[:5]), is_extended_id=False),  # dlc
        can.Message(arbitration_id=0x7E0, data=b"\x02\x01\x0d", is_extended_id=False),  # unknown id
        can.Message(arbitration_id=CODEC.command_id, is_remote_frame=True, dlc=8, is_extended_id=False),
        can.Message(arbitration_id=CODEC.command_id, data=bytes(8), is_extended_id=False),  # all zeros: crc
    ]
    try:
        for msg in garbage:
            app.send(msg)
        app.send(good)
        app.send(command(-5.0, counter=9))  # valid CRC, repeated counter: stuck
        deadline = time.monotonic() + 5
        while sum(bridge.checker.rejected.values()) < 6 and time.monotonic() < deadline:
            time.sleep(0.01)
        veh.run(bridge, 3)
    finally:
        app.shutdown()
        stats = bridge.close()
        veh.close()
    assert stats["rejected"] == {"checksum": 2, "dlc": 1, "unknown_id": 1, "remote": 1, "counter_stuck": 1}
    assert stats["rejected_total"] == 6 and stats["commands_applied"] == 1
    assert veh.a_after(0.01) == pytest.approx(3.0)  # only the good one reached the FMU
    events = [json.loads(x) for x in (tmp_path / "run" / "can-events.jsonl").read_text().splitlines()]
    reasons = [e["reason"] for e in events if e["event"] == "rejected"]
    assert sorted(reasons) == sorted(["checksum", "checksum", "dlc", "unknown_id", "remote", "counter_stuck"])
    assert all(e["detail"] for e in events if e["event"] == "rejected")


# -- [can] validation ----------------------------------------------------------------------------------
def test_parse_defaults(scenario):
    cfg = parse({"vehicle": "cav"}, scenario)
    assert cfg.bus.interface == "udp_multicast" and cfg.bus.resolved_channel() == "239.74.163.2"
    assert (cfg.status_rate_hz, cfg.command_timeout_s, cfg.on_timeout, cfg.sync) == (50.0, 0.1, "brake", "echo")
    assert cfg.variables == {"accel_input": "accel_cmd", "steer_input": "steer_cmd", "reverse_input": "reverse",
                             "speed_output": "v", "yaw_rate_output": "yaw_rate", "accel_output": "a"}
    assert cfg.resolved()["port"] == 43113


@pytest.mark.parametrize("table, key", [
    ({"vehicle": "nope"}, "can.vehicle"),
    ({}, "can.vehicle"),
    ({"vehicle": "cav", "bogus": 1}, "can.bogus"),
    ({"vehicle": "cav", "status_rate_hz": 30.0}, "can.status_rate_hz"),  # 33.3 ms is not a whole number of steps
    ({"vehicle": "cav", "status_rate_hz": -1}, "can.status_rate_hz"),
    ({"vehicle": "cav", "on_timeout": "pray"}, "can.on_timeout"),
    ({"vehicle": "cav", "sync": "maybe"}, "can.sync"),
    ({"vehicle": "cav", "command_timeout_s": 0.02}, "can.command_timeout_s"),  # shorter than a status period
    ({"vehicle": "cav", "estop_accel": 0}, "can.estop_accel"),
    ({"vehicle": "cav", "interface": "udp_multicast", "channel": "10.1.2.3"}, "can.channel"),
    ({"vehicle": "cav", "interface": "carrier_pigeon"}, "can.interface"),
    ({"vehicle": "cav", "port": 99999}, "can.port"),
    ({"vehicle": "cav", "dbc": "missing.dbc"}, "can.dbc"),
    ({"vehicle": "cav", "accel_input": "v"}, "can.accel_input"),  # an output
    ({"vehicle": "cav", "speed_output": "speed"}, "can.speed_output"),
    ({"vehicle": "other"}, "can.accel_input"),  # other.accel_cmd is driven by a connection
])
def test_parse_names_the_offending_key(scenario, table, key):
    with pytest.raises(ScenarioError) as info:
        parse(table, scenario)
    assert any(p.startswith(key + ":") for p in info.value.problems), info.value.problems
    assert str(scenario.path) in str(info.value)
    collected = []
    assert parse_can(table, scenario.instances, connections=scenario.connections, step=H,
                     problem=lambda k, m: collected.append(k)) is None
    assert key in collected


def test_echo_with_a_status_every_step_is_refused_naming_the_key(scenario, write_scenario):
    """sync = "echo" waits, before stepping from t_s + h, for the answer to the status of t_s; with a status
    every step the next status (of t_s + h) is sent first and becomes the awaited one, so the master never
    waits and the app's wall-clock speed decides when commands apply: not reproducible, refused."""
    every_step = {"vehicle": "cav", "status_rate_hz": 1.0 / H, "command_timeout_s": 0.5}
    with pytest.raises(ScenarioError) as info:
        parse(every_step, scenario)
    problems = [p for p in info.value.problems if p.startswith("can.status_rate_hz:")]
    assert len(problems) == 1 and "every step" in problems[0] and '"echo"' in problems[0], info.value.problems
    # the vehicle's own step counts: a status every second master step is every step of a vehicle stepping 2 h
    slow = load_scenario(write_scenario(SCENARIO.replace('[fmus.other]', 'step_multiple = 2\n[fmus.other]')))
    with pytest.raises(ScenarioError, match="can.status_rate_hz"):
        parse(dict(every_step, status_rate_hz=0.5 / H), slow)
    # what stays allowed: every second step, the other syncs, and realtime (echo becomes free there)
    assert parse(dict(every_step, status_rate_hz=0.5 / H), scenario).sync == "echo"
    assert parse(dict(every_step, sync="free"), scenario).status_rate_hz == 1.0 / H
    assert parse(dict(every_step, sync="drain"), scenario).status_rate_hz == 1.0 / H
    assert parse_can(every_step, scenario.instances, connections=scenario.connections, step=H,
                     mode="realtime").sync == "echo"
    # and the whole file is refused when checked (v2i validate / run), naming the key
    text = SCENARIO + '[can]\nvehicle = "cav"\nstatus_rate_hz = 100.0\ncommand_timeout_s = 0.5\n'
    with pytest.raises(ScenarioError) as info:
        load_scenario(write_scenario(text))
    assert any(p.startswith("can.status_rate_hz:") and "every step" in p for p in info.value.problems), \
        info.value.problems


# -- two processes over udp_multicast -------------------------------------------------------------------
def multicast_port() -> int | None:
    """A free UDP port on which IPv4 multicast loops back to this host, or None."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        port = s.getsockname()[1]
    try:
        a = open_bus(interface="udp_multicast", port=port)
        b = open_bus(interface="udp_multicast", port=port)
    except Exception:
        return None
    try:
        a.send(can.Message(arbitration_id=0x7FF, data=b"\x01", is_extended_id=False))
        return port if b.recv(1.0) is not None else None
    finally:
        a.shutdown()
        b.shutdown()


SENDER = textwrap.dedent("""
    import sys, time, can
    from bridges.can.bus import open_bus
    from bridges.can.codec import CavCodec, CavCommand, Mode
    codec, bus = CavCodec(), open_bus(interface="udp_multicast", port=int(sys.argv[1]))
    frames = [codec.encode_command(CavCommand(-1.5, 0.2, Mode.AUTO, False, 0, c)) for c in (1, 2, 3)]
    frames.insert(1, b"\\x00" * 8)  # garbage between good frames
    for data in frames:
        bus.send(can.Message(arbitration_id=codec.command_id, data=data, is_extended_id=False))
        time.sleep(0.02)
    bus.shutdown()
""")


def test_udp_multicast_between_two_processes(scenario, vehicle_fmu, tmp_path):
    port = multicast_port()
    if port is None:
        pytest.skip("IPv4 multicast does not loop back on this host (no multicast route on lo)")
    veh = Vehicle(vehicle_fmu, tmp_path)
    cfg = parse({"vehicle": "cav", "port": port, "sync": "free"}, scenario)
    bridge = CanBridge(cfg, "lockstep")
    (tmp_path / "run").mkdir()
    bridge.open(run_context(veh, tmp_path / "run"))
    try:
        proc = subprocess.run([sys.executable, "-c", SENDER, str(port)], cwd=ROOT, timeout=60,
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        assert bridge.wait_received(3, 5.0)
        veh.run(bridge, 2)
        steer = veh.fmu.get_by_name(["steer_cmd"])["steer_cmd"]
    finally:
        stats = bridge.close()
        veh.close()
    assert steer == pytest.approx(0.2)
    assert stats["bus"] == f"udp_multicast:239.74.163.2:{port}"
    assert (stats["commands_received"], stats["commands_applied"], stats["commands_superseded"]) == (3, 1, 2)
    assert stats["rejected"] == {"checksum": 1}
    assert stats["frames_ignored"].get("own AV_Status", 0) >= 1  # udp_multicast loops our status back
    assert veh.a_after(0.01) == pytest.approx(-1.5)


def test_v2i_run_with_a_can_table_is_reproducible_whatever_the_app_speed(write_scenario, tmp_path):
    """Through the master: [can] in a scenario file, an AV app answering every status frame."""
    from master.run.cosim import CoSimulation
    from master.scenario.loader import load_scenario

    ch = channel()
    path = write_scenario(f"""
        [time]
        stop = 1.0
        step = 0.01
        [fmus.cav]
        fmu = "{{vehicle}}"
        parameters = {{ v0 = 10.0 }}
        [record]
        variables = ["cav.v", "cav.a", "cav.accel_cmd"]
        [can]
        vehicle = "cav"
        interface = "virtual"
        channel = "{ch}"
        connect_timeout_s = 5.0
    """)
    sc = load_scenario(path)
    assert sc.resolved()["can"]["vehicle"] == "cav"
    series = []
    for seed, delay in ((1, 0.0), (2, 0.003)):
        app = EchoApp(ch, delay, seed)
        app.start()
        try:
            result = CoSimulation(sc, tmp_path / f"run{seed}", quiet=True).run()
        finally:
            app.close()
        assert result.status == "completed", result.error
        assert result.metadata["can"]["commands_applied"] > 10, result.metadata["can"]
        assert (result.run_dir / "can-applied.csv").exists()
        series.append((result.run_dir / "timeseries.csv").read_text())
    assert series[0] == series[1]
    rows = [line.split(",") for line in series[0].splitlines()[1:]]
    assert len({r[3] for r in rows}) > 3  # accel_cmd follows the app's changing requests
