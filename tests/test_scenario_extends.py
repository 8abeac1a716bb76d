"""[scenario] extends: a variant names only what differs from its base; participants switched off by enabled.

The shipped case study relies on both: ima_case_study.toml extends ima_world.toml, and ima_no_cps.toml is
ima_case_study.toml with the RSU app switched off.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from master.errors import ScenarioError
from master.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "scenarios"

BASE = """
[scenario]
name = "base"
description = "the base"
[time]
stop = 2.0
[fmus.cav]
fmu = "{vehicle}"
parameters = { v0 = 5.0, x0 = 1.0 }
[fmus.ev]
fmu = "{vehicle}"
[record]
variables = ["cav.x", "ev.x"]
"""


def test_tables_merge_key_by_key_and_values_replace(write_scenario):
    write_scenario(BASE, "base.toml")
    path = write_scenario("""
[scenario]
extends = "base.toml"
name = "variant"
[time]
stop = 3.0
[fmus.cav.parameters]
v0 = 7.0
[record]
variables = ["cav.x"]
""", "variant.toml")
    sc = load_scenario(path)
    assert sc.name == "variant" and sc.description == "the base"
    assert sc.time.stop == 3.0 and sc.time.step == 0.01
    assert sc.instances["cav"].parameters == {"v0": 7.0, "x0": 1.0}  # merged, not replaced
    assert set(sc.instances) == {"cav", "ev"}
    assert sc.record == [("cav", "x")]  # a list replaces the base's
    assert "extends" not in sc.resolved()["scenario"]  # the run folder's copy stands alone


def test_a_chain_of_bases(write_scenario):
    write_scenario(BASE, "base.toml")
    write_scenario('[scenario]\nextends = "base.toml"\nname = "middle"\n[time]\nstop = 4.0\n', "middle.toml")
    sc = load_scenario(write_scenario('[scenario]\nextends = "middle.toml"\n[fmus.ev.parameters]\nv0 = 2.0\n',
                                      "top.toml"))
    assert sc.name == "middle" and sc.time.stop == 4.0 and sc.instances["ev"].parameters == {"v0": 2.0}


@pytest.mark.parametrize("extends, reason", [
    ('"missing.toml"', "scenario.extends: cannot read"),
    ("3", "scenario.extends: expected the path of a scenario file"),
    ('"loop.toml"', "extends this file again"),
])
def test_bad_extends_is_refused_with_the_reason(write_scenario, extends, reason):
    path = write_scenario(f"[scenario]\nextends = {extends}\n", "loop.toml")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert reason in str(err.value)


def test_a_base_that_is_not_toml_is_named(write_scenario, tmp_path):
    (tmp_path / "broken.toml").write_text("[time\nstop = 1\n")
    with pytest.raises(ScenarioError, match="broken.toml is not valid TOML"):
        load_scenario(write_scenario('[scenario]\nextends = "broken.toml"\n', "child.toml"))


def test_a_problem_in_the_merged_scenario_names_the_key(write_scenario):
    write_scenario(BASE, "base.toml")
    with pytest.raises(ScenarioError, match="fmus.cav.parameters.vv0: unknown variable 'vv0'"):
        load_scenario(write_scenario('[scenario]\nextends = "base.toml"\n[fmus.cav.parameters]\nvv0 = 1.0\n',
                                     "child.toml"))


def test_a_participant_switched_off_is_neither_started_nor_waited_for(write_scenario):
    base = BASE + """
[bridge]
transport = "memory"
[participants.rsu]
role = "rsu_app"
[participants.cav]
role = "av_app"
"""
    write_scenario(base, "base.toml")
    assert set(load_scenario(write_scenario(base, "same.toml")).participants.participants) == {"rsu", "cav"}
    off = load_scenario(write_scenario('[scenario]\nextends = "base.toml"\n[participants.rsu]\nenabled = false\n',
                                       "off.toml"))
    assert set(off.participants.participants) == {"cav"}
    with pytest.raises(ScenarioError, match="participants.rsu.enabled: expected true or false"):
        load_scenario(write_scenario('[scenario]\nextends = "base.toml"\n[participants.rsu]\nenabled = "no"\n',
                                     "bad.toml"))


def test_the_shipped_case_study_and_its_no_cps_variant_differ_only_in_the_rsu_app(fmu_dir):
    cps = load_scenario(SCENARIOS / "ima_case_study.toml").resolved()
    no_cps = load_scenario(SCENARIOS / "ima_no_cps.toml").resolved()
    assert set(cps["participants"]) == {"rsu", "cav"} and set(no_cps["participants"]) == {"cav"}
    for table in ("time", "fmus", "world", "v2x", "record", "connections"):
        assert cps[table] == no_cps[table], table
    # ports of its own (so the README's two runs can go side by side), nothing else of the bus or CAN differs
    assert cps["bridge"]["listen"] != no_cps["bridge"]["listen"] and cps["can"]["port"] != no_cps["can"]["port"]
    for table, port in (("bridge", "listen"), ("can", "port")):
        assert {k: v for k, v in cps[table].items() if k != port} == \
            {k: v for k, v in no_cps[table].items() if k != port}, table
    cav = dict(no_cps["participants"]["cav"], command=[
        str(cps["can"]["port"]) if a == str(no_cps["can"]["port"]) else a for a in no_cps["participants"]["cav"]["command"]])
    assert cps["participants"]["cav"] == cav  # the same app, given its scenario's CAN port
    world = load_scenario(SCENARIOS / "ima_world.toml").resolved()
    assert cps["world"]["cameras"] == world["world"]["cameras"]  # the case study's world is ima_world's
    assert cps["fmus"]["ev"]["parameters"]["v0"] == pytest.approx(16.667)  # 60 km/h
    assert cps["fmus"]["cav"]["parameters"]["v0"] == pytest.approx(8.333)  # 30 km/h
