"""Scenario files: bad input is rejected before anything starts, naming file, key and reason."""
from __future__ import annotations

import pytest

from master.cli import main
from master.errors import ScenarioError
from master.scenario.loader import load_scenario

GOOD = """
connections = ["a.a -> b.accel_cmd"]
[time]
stop = 1.0
step = 0.1
[fmus.a]
fmu = "{vehicle}"
[fmus.a.parameters]
v0 = 5.0
[fmus.b]
fmu = "{vehicle}"
"""


def problems(write_scenario, text) -> list[str]:
    path = write_scenario(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(path) in str(info.value), "the error names the file"
    return info.value.problems


def test_good_file_loads(write_scenario):
    sc = load_scenario(write_scenario(GOOD))
    assert list(sc.instances) == ["a", "b"]
    assert sc.time.n_steps == 10 and sc.time.ordering == "jacobi" and sc.time.mode == "lockstep"
    assert [str(c) for c in sc.connections] == ["a.a -> b.accel_cmd"]
    assert sc.instances["a"].parameters == {"v0": 5.0}
    # default recording: every output of every instance
    assert ("a", "x") in sc.record and ("b", "yaw_rate") in sc.record


def test_project_fmu_by_name(write_scenario):
    sc = load_scenario(write_scenario('[time]\nstop = 1.0\nstep = 0.5\n[fmus.car]\nfmu = "VehicleDynamics"\n'))
    assert sc.instances["car"].path.name == "VehicleDynamics.fmu"


@pytest.mark.parametrize("text, key, reason", [
    (GOOD.replace("a.a -> b.accel_cmd", "c.a -> b.accel_cmd"), "connections[0]", "unknown instance 'c'"),
    (GOOD.replace("a.a -> b.accel_cmd", "a.speed -> b.accel_cmd"), "connections[0]", "unknown variable a.speed"),
    (GOOD.replace("a.a -> b.accel_cmd", "a.accel_cmd -> b.steer_cmd"), "connections[0]",
     "causality mismatch: a.accel_cmd is input"),
    (GOOD.replace("a.a -> b.accel_cmd", "a.a -> b.x"), "connections[0]", "causality mismatch: b.x is output"),
    (GOOD.replace("a.a -> b.accel_cmd", "a.a -> b.reverse"), "connections[0]", "type mismatch: a.a is Real, b.reverse is Boolean"),
    (GOOD.replace("a.a -> b.accel_cmd", "a.a to b.accel_cmd"), "connections[0]", "expected \"instance.output -> instance.input\""),
    (GOOD.replace('"a.a -> b.accel_cmd"]', '"a.a -> b.accel_cmd", "a.v -> b.accel_cmd"]'), "connections[1]",
     "b.accel_cmd is already driven by a.a -> b.accel_cmd"),
    (GOOD.replace("step = 0.1", "step = -0.1"), "time.step", "must be > 0"),
    (GOOD.replace("stop = 1.0", "stop = 0.0"), "time.stop", "must be greater than time.start"),
    (GOOD.replace("step = 0.1", "step = 0.3"), "time.stop", "not a whole number"),
    (GOOD.replace("step = 0.1", 'step = "fast"'), "time.step", "expected a finite number"),
    (GOOD.replace("step = 0.1", 'step = 0.1\nmode = "turbo"'), "time.mode", "expected one of lockstep, realtime"),
    (GOOD.replace("step = 0.1", 'step = 0.1\nordering = "random"'), "time.ordering", "expected one of jacobi, gauss-seidel"),
    (GOOD.replace("step = 0.1", 'step = 0.1\nsteps = 3'), "time.steps", "unknown key"),
    (GOOD.replace("v0 = 5.0", "v00 = 5.0"), "fmus.a.parameters.v00", "unknown variable 'v00'"),
    (GOOD.replace("v0 = 5.0", 'v0 = "fast"'), "fmus.a.parameters.v0", "expected a real value"),
    (GOOD.replace("v0 = 5.0", "accel_cmd = 1.0"), "fmus.a.parameters.accel_cmd", "causality input, not parameter"),
    (GOOD.replace("v0 = 5.0", "x = 1.0"), "fmus.a.parameters.x", "causality output, not parameter"),
    (GOOD + "[fmus.b.start]\nv0 = 1.0\n", "fmus.b.start.v0", "is a parameter"),
    (GOOD + "[fmus.b.start]\nx = 1.0\n", "fmus.b.start.x", "no settable start value"),
    (GOOD + "[fmus.b.start]\nreverse = 1\n", "fmus.b.start.reverse", "expected a boolean value"),
    (GOOD.replace('fmu = "{vehicle}"\n[fmus.a.parameters]', 'fmu = "nowhere/Missing.fmu"\n[fmus.a.parameters]'),
     "fmus.a.fmu", "FMU file not found"),
    (GOOD.replace('fmu = "{vehicle}"\n[fmus.a.parameters]', 'fmu = "NoSuchModel"\n[fmus.a.parameters]'),
     "fmus.a.fmu", "no FMU named 'NoSuchModel'"),
    (GOOD.replace('[fmus.b]\nfmu = "{vehicle}"', '[fmus.b]\nfmux = "{vehicle}"'), "fmus.b.fmu", "required"),
    (GOOD.replace('[fmus.b]', '[fmus.b]\nstep_multiple = 3'), "fmus.b.step_multiple", "does not divide the run's 10 steps"),
    (GOOD.replace('[fmus.b]', '[fmus.b]\nstep_multiple = 0'), "fmus.b.step_multiple", "expected an integer >= 1"),
    (GOOD + '[record]\nvariables = ["a.nope"]\n', "record.variables[0]", "unknown variable 'a.nope'"),
    (GOOD + '[record]\nvariables = ["z.x"]\n', "record.variables[0]", "unknown instance 'z'"),
    (GOOD + '[world]\nx = 1\n', "world", "unknown key"),
    ('[time]\nstop = 1.0\n', "fmus", "no FMU instances"),
])
def test_bad_file_names_key_and_reason(write_scenario, text, key, reason):
    found = problems(write_scenario, text)
    assert any(p.startswith(f"{key}:") and reason in p for p in found), found


def test_top_level_key_after_a_table_gets_a_hint(write_scenario):
    text = GOOD.replace('connections = ["a.a -> b.accel_cmd"]\n', "") + 'connections = ["a.a -> b.accel_cmd"]\n'
    found = problems(write_scenario, text)
    assert any(p.startswith("fmus.b.connections: unknown key") and "move `connections = ...` above" in p
               for p in found), found


def test_all_problems_are_reported_at_once(write_scenario):
    text = GOOD.replace("step = 0.1", "step = -1").replace("v0 = 5.0", "v00 = 5.0").replace("b.accel_cmd", "b.nope")
    found = problems(write_scenario, text)
    assert len(found) == 3, found


def test_suggestion_for_a_typo(write_scenario):
    found = problems(write_scenario, GOOD.replace("v0 = 5.0", "mas = 5.0"))
    assert "did you mean 'mass'" in found[0]


def test_not_toml(write_scenario):
    found = problems(write_scenario, "[time\nstop = 1")
    assert found[0].startswith("not valid TOML") and "line 1" in found[0]


def test_missing_file(tmp_path):
    with pytest.raises(ScenarioError, match="cannot read file"):
        load_scenario(tmp_path / "none.toml")


def test_validate_command(write_scenario, capsys):
    good, bad = write_scenario(GOOD), write_scenario(GOOD.replace("step = 0.1", "step = 0"))
    assert main(["validate", str(good)]) == 0
    assert "ok (2 instances, 1 connections, 10 steps" in capsys.readouterr().out
    assert main(["validate", str(good), str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: time.step: must be > 0" in err


def test_shipped_scenarios_validate():
    from pathlib import Path

    shipped = sorted((Path(__file__).parent.parent / "scenarios").glob("*.toml"))
    assert shipped
    for path in shipped:
        load_scenario(path)


def test_tuning_scenarios_validate():
    """The sequences benchmarks/rsu_app.py --tune chooses the RSU app's operating point on: each loads, and
    every vehicle it drives is one the world renders (a vehicle without looks would score as never seen)."""
    from pathlib import Path

    tuning = sorted((Path(__file__).parent / "scenarios").glob("rsu_tuning*.toml"))
    assert len(tuning) == 3
    for path in tuning:
        sc = load_scenario(path)
        assert sc.world is not None and set(sc.instances) == set(sc.world.vehicles), path


def test_fmu_without_a_binary_for_this_platform(write_scenario, vehicle_fmu, tmp_path):
    import zipfile

    stripped = tmp_path / "WinOnly.fmu"
    with zipfile.ZipFile(vehicle_fmu) as src, zipfile.ZipFile(stripped, "w") as dst:
        for item in src.infolist():
            if not item.filename.startswith("binaries/linux64/"):
                dst.writestr(item, src.read(item))
    found = problems(write_scenario, GOOD.replace('[fmus.b]\nfmu = "{vehicle}"', f'[fmus.b]\nfmu = "{stripped}"'))
    assert any(p.startswith("fmus.b.fmu:") and "no binary for this platform (linux64)" in p and "win64" in p
               for p in found), found


def test_unknown_key_in_scenario_table(write_scenario):
    found = problems(write_scenario, GOOD + '[scenario]\nnmae = "typo"\n')
    assert any(p.startswith("scenario.nmae: unknown key") for p in found), found


def test_once_per_process_fmu_cannot_have_two_instances(write_scenario, vehicle_fmu, tmp_path):
    import zipfile

    once = tmp_path / "Once.fmu"
    with zipfile.ZipFile(vehicle_fmu) as src, zipfile.ZipFile(once, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                data = data.replace(b'canBeInstantiatedOnlyOncePerProcess="false"',
                                    b'canBeInstantiatedOnlyOncePerProcess="true"')
            dst.writestr(item, data)
    text = GOOD.replace('fmu = "{vehicle}"', f'fmu = "{once}"')
    found = problems(write_scenario, text)
    assert any(p.startswith("fmus.b:") and "canBeInstantiatedOnlyOncePerProcess" in p for p in found), found


def test_unsupported_variable_kinds_are_named():
    from types import SimpleNamespace

    from master.fmi.variables import unsupported_reason

    array = SimpleNamespace(name="grid", type="Float64", dimensions=[object()])
    binary = SimpleNamespace(name="blob", type="Binary", dimensions=[])
    scalar = SimpleNamespace(name="y", type="Float64", dimensions=[])
    assert "array variable" in unsupported_reason(array)
    assert "type Binary" in unsupported_reason(binary)
    assert unsupported_reason(scalar) is None
