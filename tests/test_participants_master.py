"""Participants in master runs: [bridge]/[participants] validation, lockstep and realtime through `v2i run`."""
from __future__ import annotations

import json
import threading
import time
import tomllib
import uuid

import pytest

from bridges.timesync.participant import Participant
from master.cli import main
from master.run.cosim import CoSimulation
from master.errors import ScenarioError
from master.scenario.loader import load_scenario

BASE = """
[scenario]
name = "with-participants"
[time]
stop = {stop}
step = 0.01
mode = "{mode}"
[fmus.car]
fmu = "{vehicle}"
[fmus.car.start]
accel_cmd = 1.0
"""


def scenario(write_scenario, tables: str, stop: float = 0.2, mode: str = "lockstep"):
    return write_scenario(BASE.replace("{stop}", str(stop)).replace("{mode}", mode) + tables)


def metadata(run_dir) -> dict:
    return json.loads((run_dir / "metadata.json").read_text())


# -- validation -------------------------------------------------------------------------------------
def test_bad_tables_are_rejected_naming_every_key(write_scenario):
    path = scenario(write_scenario, """
[bridge]
transprt = "udp"
transport = "memory"
latency = "exact"
port = 70000
heartbeat_s = 2.0
heartbeat_timeout_s = 1.0
[participants.rsu]
rol = "rsu_app"
sync_every = 0
timeout_s = -1
command = "python app.py"
[participants.av]
command = ["{python}", "-m", "av_app"]
[participants."a.b"]
role = "x"
""")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    text = str(info.value)
    for expected in ("bridge.transprt: unknown key (expected one of: transport, prefix",
                     "bridge.latency: expected one of fixed, measured, got 'exact'",
                     "bridge.port: expected a port number 1..65535, got 70000",
                     "bridge.heartbeat_timeout_s: must be longer than heartbeat_s (2 s)",
                     "participants.rsu.rol: unknown key (expected one of: role, required",
                     "participants.rsu.sync_every: expected an integer >= 1",
                     "participants.rsu.timeout_s: expected wall-clock seconds > 0",
                     "participants.rsu.command: expected a non-empty list of strings",
                     "participants.av.command: the memory transport only reaches this process",
                     "participants.a.b: participant names must be letters, digits"):
        assert expected in text, f"{expected!r} not in:\n{text}"


def test_defaults_and_resolved_tables(write_scenario):
    sc = load_scenario(scenario(write_scenario, """
[participants.rsu1]
role = "rsu_app"
latencies = { detect = 0.05 }
"""))
    spec = sc.participants
    assert spec.bridge.transport == "zenoh" and spec.bridge.prefix is None and spec.bridge.latency == "fixed"
    p = spec.participants["rsu1"]
    assert p.required and p.timeout_s == 5.0 and p.sync_every == 1 and p.latencies == {"detect": 0.05}
    resolved = sc.resolved()
    assert resolved["bridge"]["prefix"] == "auto" and resolved["participants"]["rsu1"]["role"] == "rsu_app"


# -- in-process participants on the memory bus ----------------------------------------------------------
MEMORY = """
[bridge]
transport = "memory"
prefix = "{prefix}"
join_timeout_s = 5.0
heartbeat_s = 0.1
heartbeat_timeout_s = 1.0
[participants.rsu]
role = "rsu_app"
sync_every = 5
latencies = { detect = 0.05 }
[participants.av]
role = "av_app"
timeout_s = {av_timeout}
"""


def memory_app(prefix, name, role, stall_at=None):
    from bridges.transport.memory import MemoryBus

    bus = MemoryBus(prefix=prefix, sender=name)
    p = Participant(bus, name, role)
    out = {"ticks": [], "outputs": []}

    def run():
        try:
            p.join(5)
            for tick in p.ticks():
                out["ticks"].append((tick.k, tick.t))
                if tick.k == stall_at:
                    time.sleep(1.5)
                    continue
                if name == "rsu":
                    out["outputs"].append(p.output_time("detect"))
                p.ack(tick)
            out["end"] = p.ended
        finally:
            p.close()
            bus.close()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th, out


def test_lockstep_run_with_memory_participants(write_scenario, tmp_path):
    prefix = f"test/pm-{uuid.uuid4().hex[:8]}"
    path = scenario(write_scenario, MEMORY.replace("{prefix}", prefix).replace("{av_timeout}", "5.0"))
    (rsu, rsu_out), (av, av_out) = memory_app(prefix, "rsu", "rsu_app"), memory_app(prefix, "av", "av_app")
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    rsu.join(5), av.join(5)
    assert [k for k, _ in av_out["ticks"]] == list(range(20))
    assert [k for k, _ in rsu_out["ticks"]] == [0, 5, 10, 15]
    assert [t for _, t in rsu_out["ticks"]] == [k * 0.01 for k in (0, 5, 10, 15)]  # the master's own floats
    assert rsu_out["outputs"] == [k * 0.01 + 0.05 for k in (0, 5, 10, 15)]  # fixed policy: exact
    assert rsu_out["end"].status == "completed"
    meta = metadata(tmp_path / "run")
    part = meta["participants"]
    assert meta["status"] == "completed" and part["mode"] == "lockstep" and part["latency_policy"] == "fixed"
    assert part["transport"] == "memory" and part["prefix"] == prefix
    assert part["members"]["av"]["acks"] == 20 and part["members"]["rsu"]["acks"] == 4
    assert part["members"]["rsu"]["latencies_s"] == {"detect": 0.05}
    assert part["members"]["rsu"]["joined_after_s"] < 5 and part["members"]["av"]["role"] == "av_app"
    resolved = tomllib.loads((tmp_path / "run" / "scenario.resolved.toml").read_text())
    assert resolved["participants"]["rsu"]["sync_every"] == 5


def test_stalled_memory_participant_fails_the_run_naming_it(write_scenario, tmp_path):
    prefix = f"test/pm-{uuid.uuid4().hex[:8]}"
    path = scenario(write_scenario, MEMORY.replace("{prefix}", prefix).replace("{av_timeout}", "0.5"))
    (rsu, _), _ = memory_app(prefix, "rsu", "rsu_app"), memory_app(prefix, "av", "av_app", stall_at=7)
    t0 = time.perf_counter()
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert time.perf_counter() - t0 < 4
    assert result.status == "failed"
    assert result.error == "participant 'av' did not acknowledge tick 7 (t = 0.07 s) within 0.5 s"
    meta = metadata(tmp_path / "run")
    assert meta["failed_participant"] == "av" and meta["steps_done"] == 7
    assert meta["participants"]["members"]["av"]["timeouts"] == 1
    rsu.join(5)


def test_missing_participant_fails_the_run_before_the_first_step(write_scenario, tmp_path):
    path = scenario(write_scenario, MEMORY.replace("{prefix}", f"test/pm-{uuid.uuid4().hex[:8]}")
                    .replace("{av_timeout}", "1").replace("join_timeout_s = 5.0", "join_timeout_s = 0.3"))
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "failed"
    assert result.error == "participant(s) 'rsu', 'av' did not join within 0.3 s"
    meta = metadata(tmp_path / "run")
    assert meta["steps_done"] == 0 and meta["failed_participant"] == ["rsu", "av"]


# -- participant processes started by the master --------------------------------------------------------
BACKENDS = ["zenoh", "udp"]


def bus_tables(backend: str, **bridge) -> str:
    from bridges.timesync.bench import free_tcp_port

    lines = [f'transport = "{backend}"', f'prefix = "test/pp-{uuid.uuid4().hex[:8]}"',
             "heartbeat_s = 0.2", "heartbeat_timeout_s = 2.0", "join_timeout_s = 20.0"]
    if backend == "zenoh":
        lines.append(f'listen = ["tcp/127.0.0.1:{free_tcp_port()}"]')
    lines += [f"{k} = {json.dumps(v)}" for k, v in bridge.items()]
    return "[bridge]\n" + "\n".join(lines) + "\n"


def echo(name: str, *args: str, **keys) -> str:
    command = json.dumps(["{python}", "-m", "bridges.timesync.echo_participant", *args])
    extra = "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())
    return f'[participants.{name}]\nrole = "echo"\ncommand = {command}\n{extra}'


@pytest.mark.parametrize("backend", BACKENDS)
def test_lockstep_with_two_participant_processes(backend, write_scenario, tmp_path, capsys):
    path = scenario(write_scenario, bus_tables(backend) + echo("a", "--delay", "0.001") + echo("b", sync_every=2),
                    stop=0.3)
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0, capsys.readouterr().err
    part = metadata(tmp_path / "run")["participants"]
    a, b = part["members"]["a"], part["members"]["b"]
    assert a["acks"] == 30 and b["acks"] == 15 and a["timeouts"] == b["timeouts"] == 0
    assert a["pid"] != b["pid"] and a["processing_s"]["mean"] >= 0.001
    assert a["process"]["returncode"] == 0 and b["process"]["stopped"] == "exited"
    said = json.loads((tmp_path / "run" / a["log"]).read_text().strip().splitlines()[-1])
    assert said == {"name": "a", "mode": "lockstep", "end": "completed", "ticks": 30, "errors": {}}


@pytest.mark.parametrize("backend", BACKENDS)
def test_stalled_process_ends_the_run_naming_it(backend, write_scenario, tmp_path):
    path = scenario(write_scenario, bus_tables(backend) + echo("ok") + echo("hung", "--stall-after", "3", timeout_s=1.0))
    t0 = time.perf_counter()
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "failed"
    assert result.error == "participant 'hung' did not acknowledge tick 3 (t = 0.03 s) within 1 s"
    assert time.perf_counter() - t0 < 15
    hung = result.metadata["participants"]["members"]["hung"]
    assert hung["process"]["stopped"] == "terminated" and hung["acks"] == 3


@pytest.mark.parametrize("backend", BACKENDS)
def test_crashed_process_is_noticed(backend, write_scenario, tmp_path):
    path = scenario(write_scenario, bus_tables(backend) + echo("ok") + echo("crashy", "--crash-after", "4"))
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "failed"
    assert result.error.startswith("participant 'crashy' lost: its process exited with code 17")
    assert result.metadata["steps_done"] == 4 and result.metadata["failed_participant"] == "crashy"


def test_version_mismatch_is_refused_naming_both_versions(write_scenario, tmp_path):
    path = scenario(write_scenario, bus_tables("zenoh") + echo("future", "--version", "2.0"))
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "failed"
    assert "protocol version 2.0 of participant 'future' is incompatible with the master's protocol version 1.1" \
        in result.error
    meta = result.metadata["participants"]
    assert meta["refused"][0]["version"] == "2.0" and meta["members"]["future"]["process"]["returncode"] == 3
    assert "refused by the master" in (tmp_path / "run" / "participant-future.log").read_text()


def test_realtime_run_records_the_participant_clock_offset(write_scenario, tmp_path):
    path = scenario(write_scenario, bus_tables("zenoh") + echo("box", "--clock-offset", "0.25"), stop=0.5,
                    mode="realtime")
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    part = result.metadata["participants"]
    offset = part["members"]["box"]["clock_offset"]
    assert abs(offset["offset_ns"] + 250_000_000) < 5_000_000, offset
    assert part["mode"] == "realtime" and part["latency_policy"] == "realtime (wall clock)"
    assert part["ticks"] == 50 and part["members"]["box"]["acks"] == 0  # realtime never waits for acks


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_a_box_that_joins_a_running_run_follows_it_to_the_end(write_scenario, tmp_path, mode):
    """An optional box the user starts (no command) joining a run that is already ticking, as a process on
    zenoh: in lockstep its first tick was in progress when it joined, so the next one came before it acked
    (this killed it: "ack of tick 25, but the current tick is 26"); it now follows to the end and the master
    waits for it from its second tick on. In realtime it simply picks up the ticks as they come."""
    import subprocess
    import sys

    # ticks of 0.3 s (longer than the master's 0.25 s resend): the tick in progress is resent after the box's
    # join, so the box gets a tick the master is not waiting for, and works on it when the next one comes
    tables = bus_tables("zenoh") + echo("ok", "--delay", "0.3") + '[participants.box]\nrole = "echo"\n' \
        'required = false\n'
    path = scenario(write_scenario, tables, stop=0.3 if mode == "lockstep" else 4.0, mode=mode)
    sc = load_scenario(path)
    bridge = tomllib.loads(path.read_text())["bridge"]
    out = {}
    sim = threading.Thread(target=lambda: out.setdefault(
        "result", CoSimulation(sc, tmp_path / "run", quiet=True).run()), daemon=True)
    sim.start()
    deadline = time.monotonic() + 30
    while not (tmp_path / "run" / "participant-ok.log").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)  # the run is ticking
    assert sim.is_alive(), "the run ended before the box could join: make it longer"
    box = subprocess.run([sys.executable, "-m", "bridges.timesync.echo_participant", "--name", "box",
                          "--bus", "zenoh", "--prefix", bridge["prefix"], "--connect", bridge["listen"][0],
                          "--delay", "0.3"], capture_output=True, text=True, timeout=120)
    sim.join(120)
    result = out["result"]
    assert result.status == "completed", result.error
    assert box.returncode == 0, box.stderr
    said = json.loads(box.stdout.strip().splitlines()[-1])
    assert said["end"] == "completed" and said["ticks"] > 5 and said["errors"] == {}, said
    member = result.metadata["participants"]["members"]["box"]
    assert member["joined"] and member["timeouts"] == 0
    if mode == "lockstep":  # waited for from its second tick: every tick but the first acked and counted
        assert member["acks"] >= said["ticks"] - 1 and member["acks"] > 5
    else:
        assert member["acks"] == 0  # realtime never waits


def test_a_bus_that_cannot_open_fails_the_run_with_the_reason(write_scenario, tmp_path):
    path = scenario(write_scenario, '[bridge]\ntransport = "memory"\noptions = { bogus = 1 }\n[participants.a]\n')
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "failed"
    assert result.error.startswith("[bridge]: cannot open the memory bus") and "bogus" in result.error


def test_started_apps_get_the_bus_and_the_serial_ports_in_their_environment(write_scenario):
    from master.links.participants import ParticipantBridge, serial_env

    sc = load_scenario(scenario(write_scenario, bus_tables("zenoh") + echo("rsu")))
    bridge = ParticipantBridge(sc.participants, "lockstep", 1.0, "x")
    bridge.serial_urls = {"tlc": "socket://0.0.0.0:7001", "ped-2": "socket://127.0.0.1:7002"}
    env = bridge.child_env(sc.participants.participants["rsu"])
    assert env["V2I_NAME"] == "rsu" and env["V2I_BUS"] == "zenoh" and env["V2I_PREFIX"] == bridge.prefix
    assert env["V2I_SERIAL_TLC"] == "socket://127.0.0.1:7001"  # a wildcard listen is reached on loopback
    assert env[serial_env("ped-2")] == "socket://127.0.0.1:7002" and serial_env("ped-2") == "V2I_SERIAL_PED_2"
