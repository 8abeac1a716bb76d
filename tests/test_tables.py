"""The table reader every scenario section goes through, and the registry of sections.

Each getter must accept a good value, report a bad one as `dotted.key: reason`
and hand back the default so the reader finds the next problem too; a file
with faults in several sections is rejected once, listing them all.
"""
from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from master.errors import ScenarioError
from master.scenario.loader import load_scenario
from master.scenario.sections import SECTIONS, section_keys
from master.scenario.tables import Table, did_you_mean, is_number, suggest


def read(raw, prefix="can"):
    """A Table over `raw` and the problems it reports, as 'key: reason' lines."""
    found: list[str] = []
    return Table(raw, prefix, lambda k, m: found.append(f"{k}: {m}")), found


# -- numbers ------------------------------------------------------------------------------------------
def test_number_accepts_ints_and_floats_in_range_as_float():
    t, found = read({"rate": 50, "gain": 2.5})
    assert t.number("rate", 10.0, low=0, low_open=True, high=1000) == 50.0
    assert isinstance(t.number("rate", 10.0), float)
    assert t.number("gain", 1.0, low=0, high=2.5) == 2.5  # closed bound: the bound itself is in
    assert found == [] and t.ok


def test_absent_number_gives_the_default_and_required_reports_it():
    t, found = read({})
    assert t.number("rate", 50) == 50.0 and isinstance(t.number("rate", 50), float)
    assert t.number("port", None) is None
    assert found == []
    assert t.number("group", 1, integer=True, required=True, low=1, high=8) == 1
    assert found == ["can.group: required: an integer in [1, 8]"]


@pytest.mark.parametrize("bad", [True, False, "3", [1], {}, float("nan"), float("inf"), -float("inf")])
def test_bool_text_nan_and_inf_are_not_numbers(bad):
    t, found = read({"rate": bad})
    assert t.number("rate", 50.0, low=0, low_open=True) == 50.0
    assert found == [f"can.rate: expected a finite number > 0, got {bad!r}"]
    assert not t.ok and "rate" in t.failed


@pytest.mark.parametrize("value, bounds, reason", [
    (0, {"low": 0, "low_open": True}, "must be > 0, got 0"),
    (-1, {"low": 0}, "must be >= 0, got -1"),
    (5, {"high": 5, "high_open": True}, "must be < 5, got 5"),
    (6, {"high": 5}, "must be <= 5, got 6"),
    (1001.0, {"low": 0, "high": 1000, "low_open": True}, "must be in (0, 1000], got 1001.0"),
    (-100.5, {"low": -100, "high": 0}, "must be in [-100, 0], got -100.5"),
])
def test_number_out_of_range_says_the_range(value, bounds, reason):
    t, found = read({"x": value})
    assert t.number("x", 1.0, **bounds) == 1.0
    assert found == [f"can.x: {reason}"]


def test_integer_is_a_whole_number_returned_as_int():
    t, found = read({"n": 16, "m": 2.0, "f": 2.5, "b": True})
    assert t.number("n", 1, integer=True) == 16 and isinstance(t.number("n", 1, integer=True), int)
    assert t.number("m", 1, integer=True) == 2 and isinstance(t.number("m", 1, integer=True), int)
    assert t.number("f", 1, integer=True) == 1
    assert t.number("b", 1, integer=True) == 1
    assert found == ["can.f: expected an integer, got 2.5", "can.b: expected an integer, got True"]


def test_expected_words_the_whole_value():
    t, found = read({"port": 70000, "timeout_s": "soon"})
    assert t.number("port", None, low=1, high=65535, integer=True, expected="a port number 1..65535") is None
    assert t.number("timeout_s", 5.0, low=0, low_open=True, expected="wall-clock seconds > 0") == 5.0
    assert found == ["can.port: expected a port number 1..65535, got 70000",
                     "can.timeout_s: expected wall-clock seconds > 0, got 'soon'"]


def test_is_number():
    assert is_number(1) and is_number(-2.5) and is_number(10 ** 30)
    assert not any(is_number(v) for v in (True, None, "1", float("nan"), math.inf, 10 ** 400))


# -- words, flags, strings ------------------------------------------------------------------------------
def test_choice():
    t, found = read({"sync": "echo", "mode": "ecko", "other": 3})
    assert t.choice("sync", ("echo", "free"), "free") == "echo"
    assert t.choice("absent", ("echo", "free"), "free") == "free"
    assert t.choice("mode", ("echo", "free"), "free") == "free"
    assert t.choice("other", ("echo", "free"), "free") == "free"
    assert found == ["can.mode: expected one of echo, free, got 'ecko'; did you mean 'echo'?",
                     "can.other: expected one of echo, free, got 3"]


def test_boolean():
    t, found = read({"fd": True, "on": 1, "off": "false"})
    assert t.boolean("fd", False) is True and t.boolean("absent", True) is True
    assert t.boolean("on", False) is False and t.boolean("off", True) is True
    assert found == ["can.on: expected true or false, got 1", "can.off: expected true or false, got 'false'"]


def test_string():
    t, found = read({"role": "rsu_app", "empty": "", "num": 3, "prefix": "v2i/*"})
    assert t.string("role") == "rsu_app" and t.string("absent", "dflt") == "dflt"
    assert t.string("empty") is None
    assert t.string("num", expected="a role name") is None
    assert t.string("prefix", pattern=re.compile(r"^[a-z0-9/]+$"), expected="key chunks") is None
    assert t.string("name", required=True, expected="a non-empty string") is None
    assert found == ["can.empty: expected a non-empty string, got ''", "can.num: expected a role name, got 3",
                     "can.prefix: expected key chunks, got 'v2i/*'", "can.name: required: a non-empty string"]


def test_strings_and_endpoints():
    t, found = read({"one": "tcp/1.2.3.4:7447", "two": ["a", "b"], "bad": ["a", ""], "cmd": []},
                    prefix="bridge")
    assert t.endpoints("one") == ["tcp/1.2.3.4:7447"] and t.endpoints("two") == ["a", "b"]
    assert t.endpoints("absent") == []
    assert t.endpoints("bad") == []
    assert t.strings("cmd", None, nonempty=True, expected="a non-empty list of strings") is None
    assert t.strings("two", None, expected="strings") == ["a", "b"]
    assert found == ["bridge.bad: expected an endpoint string or a list of them (e.g. \"tcp/10.0.0.1:7447\"), "
                     "got ['a', '']",
                     "bridge.cmd: expected a non-empty list of strings, got []"]


# -- keys and nesting -----------------------------------------------------------------------------------
def test_unknown_keys_with_did_you_mean_and_notes():
    t, found = read({"status_rate_hz": 1, "status_rate": 2, "zzz": 3, "connections": 4})
    t.unknown_keys(("status_rate_hz", "vehicle"), notes={"connections": "move it up"})
    assert found == [
        "can.status_rate: unknown key (expected one of: status_rate_hz, vehicle); did you mean 'status_rate_hz'?",
        "can.zzz: unknown key (expected one of: status_rate_hz, vehicle)",
        "can.connections: unknown key (expected one of: status_rate_hz, vehicle); move it up"]


def test_did_you_mean_and_suggest():
    assert did_you_mean("tranport", ("transport", "prefix")) == "did you mean 'transport'?"
    assert did_you_mean("qqq", ("transport",)) is None and did_you_mean(3, ("3",)) is None
    assert suggest("mas", {"mass": 1, "x": 2}) == "did you mean 'mass'?"
    assert suggest("qqq", {"mass": 1, "x": 2}) == "2 variables; see `v2i info`"


def test_a_value_that_is_no_table_is_reported_and_read_as_empty():
    t, found = read(3, prefix="serial")
    assert t.raw == {} and not t.ok
    t2, found2 = read([1], prefix="serial")
    assert found == ["serial: expected a table, got int"] and found2 == ["serial: expected a table, got list"]
    found3: list[str] = []
    Table("x", "serial", lambda k, m: found3.append(f"{k}: {m}"), expected="a table of [serial.NAME] tables")
    assert found3 == ["serial: expected a table of [serial.NAME] tables, got str"]


def test_sub_tables_carry_the_dotted_prefix_and_count_for_their_parent():
    t, found = read({"vehicles": {"cav": {"lidar": {"channels": 0}}}, "options": 3}, prefix="world")
    lidar = t.sub("vehicles").sub("cav").sub("lidar")
    assert lidar.prefix == "world.vehicles.cav.lidar" and lidar.ok
    assert lidar.number("channels", 16, low=0, low_open=True, integer=True) == 16
    assert found == ["world.vehicles.cav.lidar.channels: must be > 0, got 0"]
    assert not lidar.ok and not t.ok and t.reported == 1
    assert t.sub("absent").raw == {} and t.sub("absent").ok
    options = t.sub("options", "a table of options")
    assert not options.ok and options.raw == {}
    assert found[-1] == "world.options: expected a table of options, got int"
    item = Table({"name": ""}, "world.buildings[0]", parent=t)
    item.string("name", required=True)
    assert found[-1] == "world.buildings[0].name: expected a non-empty string, got ''" and t.reported == 3


def test_the_root_table_has_no_prefix():
    t, found = read({"tim": {}}, prefix="")
    t.unknown_keys(("time",))
    assert found == ["tim: unknown key (expected one of: time); did you mean 'time'?"]
    assert t.sub("time").prefix == "time"


# -- instances and FMU variables --------------------------------------------------------------------------
def _instance(name="cav", **variables):
    return SimpleNamespace(name=name, variables={n: SimpleNamespace(name=n, causality=c, type=ty)
                                                  for n, (c, ty) in variables.items()})


def test_instance():
    cav = _instance()
    t, found = read({"vehicle": "cav", "other": "bus", "blank": ""})
    assert t.instance("vehicle", {"cav": cav}, "the vehicle") is cav
    assert t.instance("other", {"cav": cav}, "the vehicle") is None
    assert t.instance("blank", {"cav": cav}, "the vehicle") is None
    assert t.instance("absent", {}, "the vehicle") is None
    assert found == ["can.other: unknown instance 'bus' (instances: cav)", "can.blank: required: the vehicle",
                     "can.absent: required: the vehicle"]


def test_fmu_variable_checks_causality_and_type():
    cav = _instance(accel_cmd=("input", "Real"), v=("output", "Real"), reverse=("input", "Boolean"),
                    mass=("parameter", "Real"))
    t, found = read({"accel_input": "accel_cmd", "speed_output": "vv", "mass_input": "mass", "flag": "v", "n": 3})
    assert t.fmu_variable("accel_input", cav, causality="input", family="real") == "accel_cmd"
    assert t.fmu_variable("absent", cav, causality="input", family="boolean", default="reverse") == "reverse"
    assert t.fmu_variable("opt", cav, causality="output", family="real", default="yaw_rate", required=False) is None
    assert t.fmu_variable("speed_output", cav, causality="output", family="real") is None
    assert t.fmu_variable("mass_input", cav, causality="input", family="real") is None
    assert t.fmu_variable("flag", cav, causality="output", family="boolean") is None
    assert t.fmu_variable("n", cav, causality="output", family="real") is None
    assert t.fmu_variable("n", None, causality="output", family="real") is None
    assert t.fmu_variable("speed_output", None, causality="output", family="real") == "vv"  # no instance: name only
    assert found == [
        "can.speed_output: unknown variable cav.vv (did you mean 'v'?)",
        "can.mass_input: cav.mass is a parameter of type Real; expected a real input",
        "can.flag: cav.v is an output of type Real; expected a boolean output",
        "can.n: expected a variable name of cav, got 3",
        "can.n: expected a variable name, got 3"]


# -- the sections -----------------------------------------------------------------------------------------
def test_every_section_names_a_reader_that_exists():
    assert section_keys() == ("serial", "world", "bridge", "participants", "can", "v2x", "pki", "events")
    for section in SECTIONS:
        assert callable(section.load()), section


def test_a_scenario_without_sections_imports_no_section_module(fmu_dir):
    """The readers are imported only for the sections a file has: no pybullet, python-can or zenoh for the rest."""
    code = ("import sys; from master.scenario.loader import load_scenario; load_scenario('scenarios/two_vehicles.toml'); "
            "print(sorted(m for m in ('pybullet', 'can', 'zenoh', 'torch', 'master.links.can_bridge', "
            "'master.world.layout', 'master.links.participants', 'master.links.radio_bridge', 'master.links.serial_bridge') "
            "if m in sys.modules))")
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120,
                         env={**os.environ, "V2I_FMU_DIR": str(fmu_dir)})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


BAD_SECTIONS = """
[time]
stop = 1.0
step = 0.01
[fmus.cav]
fmu = "{vehicle}"
[fmus.tlc]
fmu = "{tlc}"
[serial.port]
instance = "nope"
[world.intersection]
road_widht = 7.0
[can]
vehicle = "cav"
status_rate_hz = -1
on_timeout = "pray"
[v2x]
mode = "air"
[v2x.stations.rsu]
position = [0.0, 0.0, 5.0]
[participants.rsu]
sync_every = 0
timeout_s = -1
"""


def test_every_problem_of_every_section_in_one_error(write_scenario, fmu_dir):
    path = write_scenario(BAD_SECTIONS.replace("{tlc}", str(fmu_dir / "TrafficLightController.fmu")))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    expected = [
        "serial.port.instance: unknown instance 'nope'",
        "world.intersection.road_widht: unknown key (expected one of: road_width",
        "can.status_rate_hz: must be in (0, 1000], got -1",
        "can.on_timeout: expected one of brake, zero_accel, hold, manual, got 'pray'",
        "participants.rsu.sync_every: expected an integer >= 1",
        "participants.rsu.timeout_s: expected wall-clock seconds > 0",
        "v2x.mode: expected one of channel, bypass, rsu, got 'air'",
        "v2x: needs a [bridge] table",
    ]
    problems = info.value.problems
    for line in expected:
        assert any(p.startswith(line) for p in problems), (line, problems)
    assert len(problems) == len(expected), problems
    assert "did you mean 'road_width'" in str(info.value)
    assert all(f"{path}: {p}" in str(info.value) for p in problems), "each line is file: key: reason"
