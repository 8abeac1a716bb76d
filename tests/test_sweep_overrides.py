"""`--set KEY=VALUE` (master.scenario.overrides): parsing and typing of values, key paths into tables and arrays of
tables, refusal of what cannot land, validation of the merged scenario with the loader's own messages, and
`v2i run --set` end to end (the run folder's resolved scenario shows the value)."""
from __future__ import annotations

import math
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from master.errors import ScenarioError
from master.scenario.overrides import (OverrideError, Segment, apply_overrides, parse_key, parse_override, parse_value,
                              toml_literal)
from master.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).parent / "v2i"
TWO_VEHICLES = ROOT / "scenarios" / "two_vehicles.toml"
IMA_WORLD = ROOT / "scenarios" / "ima_world.toml"


# -- values -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("text, value, kind", [
    ("20.1", 20.1, float), ("20", 20, int), ("-3", -3, int), ("1e3", 1000.0, float), ("true", True, bool),
    ("false", False, bool), ("cv2x", "cv2x", str), ('"30"', "30", str), ("'a b'", "a b", str),
    ("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7447", str), ("07", "07", str), ("2.4.1", "2.4.1", str),
    ("[1, 2]", [1, 2], list), ('["--hardware", "cpu-i7"]', ["--hardware", "cpu-i7"], list),
    ("{ detect = 0.2 }", {"detect": 0.2}, dict), ("[]", [], list), ("inf", math.inf, float),
])
def test_a_value_is_a_toml_literal_else_a_bare_word(text, value, kind):
    parsed = parse_value(text)
    assert parsed == value and type(parsed) is kind


@pytest.mark.parametrize("text", ["hello world", "", "1\nx = 2", "a,b", "[1, 2", '"open'])
def test_a_value_that_is_neither_is_refused(text):
    with pytest.raises(ValueError, match="neither a TOML value nor a bare word|no value"):
        parse_value(text)


def test_keys_with_quoted_parts_and_selectors():
    assert parse_key("fmus.ev.parameters.v0") == tuple(Segment(k) for k in ("fmus", "ev", "parameters", "v0"))
    assert parse_key('world.cameras[rsu_cam].z') == (Segment("world"), Segment("cameras", ("rsu_cam",)),
                                                     Segment("z"))
    assert parse_key('world.buildings[0].height')[1] == Segment("buildings", (0,))
    assert parse_key('v2x."my.key"') == (Segment("v2x"), Segment("my.key"))
    for bad in ("", "a..b", "a.", "a[0", "a b", "a.[0]"):
        with pytest.raises(ValueError):
            parse_key(bad)


def test_an_override_needs_an_equals_sign():
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        parse_override("time.stop")
    o = parse_override("time.stop = 4.0")
    assert (o.key, o.value) == ("time.stop", 4.0)


_scalars = st.one_of(st.booleans(), st.integers(-2**63, 2**63 - 1),
                     st.floats(allow_nan=False), st.text(max_size=20))
_values = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(min_size=1, max_size=8), inner, max_size=4)), max_leaves=12)


@settings(max_examples=200, deadline=None)
@given(_values)
def test_toml_literal_round_trips(value):
    """What a sweep passes to `v2i run --set` is read back as the same value (type included)."""
    assert parse_value(toml_literal(value)) == value
    assert tomllib.loads(f"v = {toml_literal(value)}")["v"] == value


# -- applying -----------------------------------------------------------------------------------------------
def test_apply_sets_merges_and_creates_tables():
    raw = {"time": {"stop": 8.0}, "participants": {"rsu": {"latencies": {"detect": 0.05, "sign": 0.002}}},
           "world": {"cameras": [{"name": "a", "z": 6.0}, {"name": "b", "z": 5.0}]}}
    out, where = apply_overrides(raw, [parse_override(t) for t in (
        "time.stop=4.0", "participants.rsu.latencies={ detect = 0.2 }", "v2x.channel.loss_prob=0.3",
        "world.cameras[b].z=9.0", "world.cameras[0].z=7.0")])
    assert out["time"]["stop"] == 4.0
    assert out["participants"]["rsu"]["latencies"] == {"detect": 0.2, "sign": 0.002}  # a table merges
    assert out["v2x"] == {"channel": {"loss_prob": 0.3}}
    assert [c["z"] for c in out["world"]["cameras"]] == [7.0, 9.0]
    assert raw["time"]["stop"] == 8.0  # the input is not touched
    assert where["world.cameras[1].z"] == "world.cameras[b].z=9.0"  # named as the loader names keys


@pytest.mark.parametrize("text, message", [
    ("time.stop.x=1", "time.stop is a number, not a table"),
    ("world.cameras[9].z=1", r"world.cameras\[9\]: index out of range \(world.cameras has 2 element"),
    ("world.cameras[c].z=1", "no element named 'c'"),
    ("world.cameras[aa].z=1", "did you mean 'a'"),
    ("time[0]=1", "time is a table, not an array"),
    ("wrld.cameras[0].z=1", "wrld.cameras is not in the scenario.*did you mean 'world'"),
])
def test_apply_refuses_what_cannot_land(text, message):
    raw = {"time": {"stop": 8.0}, "world": {"cameras": [{"name": "a"}, {"name": "b"}]}}
    with pytest.raises(OverrideError, match=message):
        apply_overrides(raw, [parse_override(text)])


# -- the scenario -------------------------------------------------------------------------------------------
def test_load_scenario_with_overrides_types_and_lists_them(fmu_dir):
    sc = load_scenario(TWO_VEHICLES, ["fmus.ev.parameters.v0=20.1", "time.stop=4", "time.mode=realtime"])
    assert sc.instances["ev"].parameters["v0"] == 20.1
    assert sc.time.stop == 4.0 and sc.time.mode == "realtime"
    resolved = sc.resolved()
    assert resolved["fmus"]["ev"]["parameters"]["v0"] == 20.1
    assert resolved["scenario"]["overrides"] == ["fmus.ev.parameters.v0=20.1", "time.stop=4", "time.mode=realtime"]


def test_unknown_keys_are_refused_like_the_files_own(fmu_dir, tmp_path):
    """The merged scenario is validated as a whole: the same message (and did-you-mean) as the key in the
    file would get, with the --set it came from."""
    with pytest.raises(ScenarioError) as by_set:
        load_scenario(TWO_VEHICLES, ["fmus.ev.parameters.vv0=20.1", "time.mode=realtim", "tme.stop=3"])
    problems = by_set.value.problems
    assert any(p.startswith("fmus.ev.parameters.vv0: unknown variable 'vv0'") and "did you mean 'v0'" in p
               and p.endswith("(from --set fmus.ev.parameters.vv0=20.1)") for p in problems), problems
    assert any(p.startswith("time.mode: expected one of lockstep, realtime, got 'realtim'; did you mean "
                            "'realtime'?") for p in problems), problems
    assert any(p.startswith("tme: unknown key") and "did you mean 'time'" in p for p in problems), problems
    text = TWO_VEHICLES.read_text().replace("v0 = 16.667", "vv0 = 16.667")
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ScenarioError) as in_file:
        load_scenario(tmp_path / "bad.toml")
    in_file_problem = next(p for p in in_file.value.problems if p.startswith("fmus.ev.parameters.vv0"))
    assert in_file_problem in problems[[p.startswith("fmus.ev.parameters.vv0") for p in problems].index(True)]


def test_array_elements_by_name_and_a_removed_building(fmu_dir):
    sc = load_scenario(IMA_WORLD, ["world.cameras[rsu_cam].z=10.0", "world.buildings=[]"])
    assert sc.world.cameras[0].z == 10.0 and sc.world.buildings == []
    with pytest.raises(ScenarioError, match=r"world.buildings\[0\].heigth: unknown key .*did you mean 'height'"):
        load_scenario(IMA_WORLD, ["world.buildings[sw_corner].heigth=30"])


def v2i(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(V2I), *args], capture_output=True, text=True, timeout=120, cwd=ROOT)


def test_v2i_run_set_end_to_end(fmu_dir, tmp_path):
    out = tmp_path / "run"
    r = v2i("run", str(TWO_VEHICLES), "--set", "fmus.ev.parameters.v0=20.1", "--set", "time.stop=2.0",
            "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    resolved = tomllib.loads((out / "scenario.resolved.toml").read_text())
    assert resolved["fmus"]["ev"]["parameters"]["v0"] == 20.1
    assert resolved["time"]["stop"] == 2.0
    assert resolved["scenario"]["overrides"] == ["fmus.ev.parameters.v0=20.1", "time.stop=2.0"]
    rows = (out / "timeseries.csv").read_text().splitlines()
    header = rows[0].split(",")
    first = dict(zip(header, rows[1].split(",")))
    assert float(first["ev.v"]) == pytest.approx(20.1, abs=0.01)  # the FMU ran with the value
    assert float(rows[-1].split(",")[0]) == pytest.approx(2.0)
    again = tmp_path / "again"  # the resolved scenario runs again as it is (its overrides are informative)
    r = v2i("run", str(out / "scenario.resolved.toml"), "--out", str(again), "--quiet")
    assert r.returncode == 0, r.stderr


def test_v2i_run_and_validate_refuse_a_bad_set(fmu_dir, tmp_path):
    r = v2i("run", str(TWO_VEHICLES), "--set", "fmus.ev.parameters.v00=1", "--out", str(tmp_path / "x"))
    assert r.returncode == 2
    assert "fmus.ev.parameters.v00: unknown variable 'v00'" in r.stderr and "did you mean 'v0'" in r.stderr
    assert not (tmp_path / "x").exists()
    r = v2i("validate", str(TWO_VEHICLES), "--set", "x=hello world")
    assert r.returncode == 2 and "--set x=hello world: 'hello world' is neither" in r.stderr
