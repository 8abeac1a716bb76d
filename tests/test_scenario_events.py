"""Scenario events ([[events]]): checked with the file, executed at their time or when their condition first
holds, each in events.jsonl with its time; kill, stop and pause of app processes; set; injections on the air,
the CAN bus and a serial link."""
from __future__ import annotations

import csv
import json
import time
import uuid

import pytest

from master.run.cosim import CoSimulation
from master.errors import ScenarioError
from master.scenario.loader import load_scenario

BASE = """
[scenario]
name = "events"
[time]
stop = {stop}
step = 0.01
[fmus.car]
fmu = "{{vehicle}}"
[fmus.car.parameters]
v0 = 10.0
[record]
variables = ["car.v", "car.accel_cmd"]
"""


def scenario(write_scenario, tables: str, stop: float = 1.0):
    return write_scenario(BASE.format(stop=stop) + tables)


def events_of(run_dir, action: str | None = None) -> list[dict]:
    out = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    return [e for e in out if e.get("event") == "scenario_event" and (action is None or e["action"] == action)]


def series(run_dir) -> list[dict]:
    with open(run_dir / "timeseries.csv") as f:
        return list(csv.DictReader(f))


def echo(name: str, *args: str, **keys) -> str:
    command = json.dumps(["{python}", "-m", "bridges.timesync.echo_participant", *args])
    extra = "".join(f"{k} = {json.dumps(v)}\n" for k, v in keys.items())
    return f'[participants.{name}]\nrole = "echo"\ncommand = {command}\n{extra}'


def bridge(**keys) -> str:
    from bridges.timesync.bench import free_tcp_port

    lines = ['transport = "zenoh"', f'prefix = "test/ev-{uuid.uuid4().hex[:8]}"', "heartbeat_s = 0.2",
             "heartbeat_timeout_s = 2.0", "join_timeout_s = 20.0", f'listen = ["tcp/127.0.0.1:{free_tcp_port()}"]']
    lines += [f"{k} = {json.dumps(v)}" for k, v in keys.items()]
    return "[bridge]\n" + "\n".join(lines) + "\n"


# -- checked with the file ----------------------------------------------------------------------------
def test_every_bad_event_is_named_with_its_key(write_scenario):
    path = scenario(write_scenario, """
[[events]]
at = 0.5
action = "kil"
[[events]]
at = 0.2
when = "car.v < 1"
action = "set"
target = "car.acel_cmd"
value = 1.0
[[events]]
at = 7.0
action = "inject_v2x"
station = "rsu"
hex = "zz"
[[events]]
when = "car.speed > 1"
action = "inject_can"
count = 3
[[events]]
at = 0.1
action = "pause"
participant = "rsu"
wall_s = 1.0
colour = "red"
""")
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    text = str(info.value)
    for expected in ("events[0].action: expected one of kill, stop, pause",
                     "did you mean 'kill'",
                     "events[1].at: give exactly one of `at` (simulated seconds) or `when`",
                     "events[1].target: 'car' has no variable 'acel_cmd'; did you mean 'accel_cmd'",
                     "events[2].at: expected simulated seconds in 0..1 (the run's stop), got 7.0",
                     "events[2].station: no station 'rsu' in [v2x.stations]",
                     "events[2].hex: not hexadecimal",
                     "events[3].when:", "car.speed",
                     "events[3].action: inject_can needs the scenario's [can] table",
                     "events[4].participant: no [participants.rsu] in the scenario",
                     "events[4].colour: unknown key for action 'pause'"):
        assert expected in text, f"{expected!r} not in:\n{text}"


def test_a_participant_the_master_does_not_start_cannot_be_signalled(write_scenario):
    path = scenario(write_scenario, bridge() + '[participants.box]\nrole = "rsu_app"\n'
                    '[[events]]\nat = 0.1\naction = "kill"\nparticipant = "box"\n')
    with pytest.raises(ScenarioError, match=r"events\[0\].participant: participant 'box' is not started by the "
                                            r"master \(no command\)"):
        load_scenario(path)


# -- at a time, when a condition holds ----------------------------------------------------------------
def test_set_at_a_time_and_when_a_condition_first_holds(write_scenario, tmp_path):
    path = scenario(write_scenario, """
[[events]]
at = 0.25
action = "set"
target = "car.accel_cmd"
value = 2.0
[[events]]
when = "car.v > 10.5"
action = "set"
target = "car.accel_cmd"
value = -1.0
""")
    sc = load_scenario(path)
    assert sc.resolved()["events"][1] == {"action": "set", "when": "car.v > 10.5", "target": "car.accel_cmd",
                                          "value": -1.0}
    result = CoSimulation(sc, tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    rows = series(tmp_path / "run")
    cmd = {round(float(r["time"]), 2): float(r["car.accel_cmd"]) for r in rows}
    # set before the step from t = 0.25; a row holds the inputs of the step that ended at its time
    assert cmd[0.25] == 0.0 and cmd[0.26] == 2.0
    # the condition first holds at the end of some step (the first row with v > 10.5): it acts before the next
    held = next(round(float(r["time"]), 2) for r in rows if float(r["car.v"]) > 10.5)
    fired = events_of(tmp_path / "run")
    assert [(e["action"], e["t"]) for e in fired] == [("set", 0.25), ("set", pytest.approx(held))]
    assert cmd[held] == 2.0 and cmd[round(held + 0.01, 2)] == -1.0
    assert [e["t"] for e in result.metadata["scenario_events"]["executed"]] == [0.25, pytest.approx(held)]


def test_an_event_whose_time_never_comes_is_reported_not_reached(write_scenario, tmp_path):
    path = scenario(write_scenario, '[[events]]\nwhen = "car.v < 1"\naction = "set"\ntarget = "car.accel_cmd"\n'
                                    'value = 0.0\n')
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.metadata["scenario_events"]["not_reached"] == [{"action": "set", "when": "car.v < 1",
                                                                  "target": "car.accel_cmd", "value": 0.0}]
    assert not (tmp_path / "run" / "events.jsonl").exists() or events_of(tmp_path / "run") == []


# -- app processes ------------------------------------------------------------------------------------
def test_killing_a_required_app_ends_the_run_naming_it(write_scenario, tmp_path):
    path = scenario(write_scenario, bridge() + echo("a") + echo("b") +
                    '[[events]]\nat = 0.3\naction = "kill"\nparticipant = "b"\n', stop=2.0)
    t0 = time.monotonic()
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert time.monotonic() - t0 < 30
    assert result.status == "failed" and result.error.startswith("participant 'b' lost: its process exited")
    assert 0.3 <= result.metadata["sim_time_reached_s"] < 0.5
    (killed,) = events_of(tmp_path / "run", "kill")
    assert killed["t"] == pytest.approx(0.3) and killed["participant"] == "b" and killed["pid"] > 0


def test_stopping_an_optional_app_drops_it_and_the_run_goes_on(write_scenario, tmp_path):
    path = scenario(write_scenario, bridge() + echo("a") + echo("b", required=False) +
                    '[[events]]\nat = 0.3\naction = "stop"\nparticipant = "b"\n', stop=1.0)
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    members = result.metadata["participants"]["members"]
    assert members["a"]["acks"] == 100 and members["b"]["acks"] < 40
    assert events_of(tmp_path / "run", "stop")[0]["t"] == pytest.approx(0.3)


def test_a_short_pause_delays_a_lockstep_run_and_a_long_one_ends_it(write_scenario, tmp_path):
    short = scenario(write_scenario, bridge() + echo("a", timeout_s=3.0) +
                     '[[events]]\nat = 0.2\naction = "pause"\nparticipant = "a"\nwall_s = 1.0\n', stop=0.5)
    t0 = time.monotonic()
    result = CoSimulation(load_scenario(short), tmp_path / "short", quiet=True).run()
    assert result.status == "completed", result.error
    assert time.monotonic() - t0 >= 1.0  # the master waited for the stopped app
    phases = [e.get("phase", "start") for e in events_of(tmp_path / "short", "pause")]
    assert phases == ["start", "end"]
    long = scenario(write_scenario, bridge() + echo("a", timeout_s=1.0) +
                    '[[events]]\nat = 0.2\naction = "pause"\nparticipant = "a"\nwall_s = 5.0\n', stop=0.5)
    result = CoSimulation(load_scenario(long), tmp_path / "long", quiet=True).run()
    assert result.status == "failed"
    assert result.error == "participant 'a' did not acknowledge tick 20 (t = 0.2 s) within 1 s"


# -- injections ---------------------------------------------------------------------------------------
def test_a_frame_injected_on_the_air_is_sent_as_if_the_station_transmitted_it(write_scenario, tmp_path):
    path = scenario(write_scenario, '[bridge]\ntransport = "memory"\n' + """
[v2x]
[v2x.stations.rsu]
position = [0.0, 0.0, 5.0]
[v2x.stations.car]
vehicle = "car"
[[events]]
at = 0.5
action = "inject_v2x"
station = "rsu"
hex = "00 14 25 de ad be ef"
count = 3
""")
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    lines = [json.loads(x) for x in (tmp_path / "run" / "events.jsonl").read_text().splitlines()]
    sent = [e for e in lines if e.get("event") == "v2x_sent" and e.get("from") == "rsu"]
    assert len(sent) == 3 and all(e["t"] == pytest.approx(0.5) for e in sent)
    (injected,) = events_of(tmp_path / "run", "inject_v2x")
    assert injected["bytes"] == 7 and injected["t"] == 0.5


def test_garbage_on_the_can_bus_is_tallied_and_never_stops_the_run(write_scenario, tmp_path):
    from test_can_bridge import channel

    path = scenario(write_scenario, f"""
[can]
vehicle = "car"
interface = "virtual"
channel = "{channel()}"
[[events]]
at = 0.2
action = "inject_can"
count = 40
seed = 3
[[events]]
at = 0.4
action = "inject_can"
can_id = 0x100
data = "ffffffffffffffff"
""")
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    can = result.metadata["can"]
    assert can["injected"] == 41
    assert can["rejected_total"] + sum(can["frames_ignored"].values()) >= 1, can
    assert [e["frames"] for e in events_of(tmp_path / "run", "inject_can")] == [40, 1]


def test_garbage_on_a_serial_link_reaches_the_controller_which_counts_it(tmp_path):
    import test_serial_bridge as sb

    text = sb.SCENARIO.read_text().replace("stop = 120.0", "stop = 1.0") + """
[[events]]
at = 0.3
action = "inject_serial"
serial = "tlc"
garbage = 64
seed = 1
"""
    path = tmp_path / "s.toml"
    path.write_text(text.replace('fmu = "TrafficLightController"', f'fmu = "{sb_fmu()}"'))
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    log = [json.loads(x) for x in (tmp_path / "run" / "serial-tlc.jsonl").read_text().splitlines()]
    assert {"t": 0.3, "event": "inject", "to": "fmu", "n": 64}.items() <= log[1].items()
    rx = [e for e in log if e["event"] == "rx"]
    assert rx and rx[0]["t"] == pytest.approx(0.3) and rx[0]["n"] == 64
    assert events_of(tmp_path / "run", "inject_serial")[0]["bytes"] == 64


def sb_fmu():
    from fmus.builder import build_all
    from pathlib import Path

    (result,) = build_all(Path(__file__).resolve().parent.parent / "build" / "fmus", only=["TrafficLightController"])
    return result.path


def test_a_link_event_drops_or_delays_that_links_frames_for_its_period(write_scenario, tmp_path):
    path = scenario(write_scenario, '[bridge]\ntransport = "memory"\n' + """
[v2x]
[v2x.stations.rsu]
position = [0.0, 0.0, 5.0]
[v2x.stations.car]
vehicle = "car"
[v2x.stations.other]
position = [5.0, 0.0, 1.5]
[[events]]
at = 0.1
action = "link"
link = "rsu->car"
loss = 1.0
duration_s = 0.4
[[events]]
at = 0.2
action = "inject_v2x"
station = "rsu"
hex = "0014"
count = 4
[[events]]
at = 0.6
action = "link"
link = "*->car"
delay_s = 0.05
[[events]]
at = 0.7
action = "inject_v2x"
station = "rsu"
hex = "0014"
""")
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    lines = [json.loads(x) for x in (tmp_path / "run" / "events.jsonl").read_text().splitlines()]
    to_car = [e for e in lines if e.get("to") == "car" and e["event"] in ("v2x_dropped", "v2x_delivered")]
    early, late = [e for e in to_car if e["t"] < 0.5], [e for e in to_car if e["t"] >= 0.5]
    assert [(e["event"], e["reason"]) for e in early] == [("v2x_dropped", "event")] * 4
    to_other = [e for e in lines if e.get("to") == "other" and e["event"] == "v2x_delivered" and e["t"] < 0.5]
    assert len(to_other) == 4  # only the named link was cut
    (delivered,) = late
    assert delivered["event"] == "v2x_delivered" and delivered["latency_s"] >= 0.05
    ends = [e for e in events_of(tmp_path / "run", "link") if e.get("phase") == "end"]
    assert [e["t"] for e in ends] == [pytest.approx(0.5)]
