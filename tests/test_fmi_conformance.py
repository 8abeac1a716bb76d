"""The master's FMI conformance with third-party FMUs (issue 19): value ranges, consistent
initialization, scheduled execution, input files and FMI 3 arrays.

The FMUs are compiled from C during the test (tests/third_party_fmu/build.py):

* Conformance3 (FMI 3.0 CS), outputs computed from the current inputs whenever read:
      y = gain * x,  count_out = count,  on_out = on          (direct feedthrough)
      v_out[j] = gain * v_in[j] + offsets[j],  v_sum = sum(v_in)   (Float64[3] arrays)
      x_int += x * h in each doStep                            (no feedthrough)
  plus i8 (Int8, min -100, max 100), u8 (UInt8), u64 (UInt64 parameter),
  f32 (Float32), ratio (declared type Ratio: [0, 1]), level (discrete Real input),
  w_in (Float64[2] input).
* Clocked3: an FMI 3 model description with a ScheduledExecution interface only.
* Integrator (FMI 2.0 CS, see tests/test_third_party_fmu.py): k has min -1000, max 1000;
  n_steps is an Integer (a C int).

Every expected value below is computed by hand in the test's comments.
"""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from master.cli import main as cli_main
from master.run.cosim import CoSimulation
from master.errors import ScenarioError
from master.scenario.loader import load_scenario
from test_third_party_fmu import c_fmu_builder

H = 0.1
TIMES = [round(H * n, 10) for n in range(11)]  # 0.0 .. 1.0


@pytest.fixture(scope="session")
def fmus(tmp_path_factory) -> dict[str, Path]:
    """{model identifier: .fmu}: Conformance3, Clocked3 and Integrator (FMI 2), compiled once."""
    build = c_fmu_builder()
    out = tmp_path_factory.mktemp("conformance_fmus")
    built = build.build_conformance(out)
    built["Integrator"] = build.build_fmu(2, out)
    return built


def scenario(directory: Path, text: str, fmus: dict[str, Path], files: dict[str, str] | None = None) -> Path:
    """A scenario file beside copies of the FMUs (and any input files), referenced by relative path."""
    directory.mkdir(parents=True, exist_ok=True)
    for fmu in fmus.values():
        if not (directory / fmu.name).exists():
            shutil.copy(fmu, directory / fmu.name)
    for name, content in (files or {}).items():
        (directory / name).write_text(content)
    path = directory / "scenario.toml"
    path.write_text(text)
    return path


def problems_of(path: Path) -> list[str]:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(path) in str(info.value)
    return info.value.problems


def assert_problem(problems: list[str], key: str, *fragments: str) -> None:
    """One problem starts with `key: ` and holds every fragment."""
    hits = [p for p in problems if p.startswith(f"{key}: ") and all(f in p for f in fragments)]
    assert hits, f"no problem for {key} with {fragments}; got:\n" + "\n".join(problems)


def run(path: Path, run_dir: Path):
    result = CoSimulation(load_scenario(path), run_dir, quiet=True).run()
    meta = json.loads((run_dir / "metadata.json").read_text())
    return result, meta


def columns(run_dir: Path) -> dict[str, list[str]]:
    """timeseries.csv as text, column by column (so integers are compared as written)."""
    with open(run_dir / "timeseries.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows, "timeseries.csv has no rows"
    return {name: [r[name] for r in rows] for name in rows[0]}


def numbers(run_dir: Path) -> dict[str, list[float]]:
    return {name: [float(v) for v in values] for name, values in columns(run_dir).items()}


TIME = """
[time]
stop = 1.0
step = 0.1
"""


# ------------------------------------------------------- 1. values out of range or type
def test_values_out_of_a_variables_range_are_refused_when_the_scenario_is_checked(fmus, tmp_path):
    # before: Int8 300 was set as 44, UInt8 -1 as 255, UInt64 2**64 as 0, Float32 1e300 as inf
    text = TIME + """
[fmus.c]
fmu = "Conformance3.fmu"
[fmus.c.parameters]
u64 = 18446744073709551616      # 2**64
ratio = 1.5                     # declared type Ratio: max 1
offsets = [1.0, 2.0]            # a Float64[3]
[fmus.c.start]
i8 = 300
u8 = -1
f32 = 1e300
v_in = [1.0, 2.0, 1e400]        # TOML reads 1e400 as inf: fine for a Float64, no wrap

[fmus.d]
fmu = "Conformance3.fmu"
[fmus.d.start]
i8 = 101                        # Int8 range, but above the declared max 100
u8 = 2.5                        # not an integer

[fmus.old]
fmu = "Integrator.fmu"
[fmus.old.parameters]
k = 1001.0                      # FMI 2 <Real max="1000">
[fmus.old.start]
n_steps = 2147483648            # 2**31: outside an FMI 2 Integer (C int)
"""
    found = problems_of(scenario(tmp_path / "sc", text, fmus))
    assert_problem(found, "fmus.c.parameters.u64", "18446744073709551616", "UInt64", "[0, 18446744073709551615]",
                   "wrap")
    assert_problem(found, "fmus.c.parameters.ratio", "1.5 is above the declared max 1 of 'ratio' (declared type Ratio)")
    assert_problem(found, "fmus.c.parameters.offsets", "Float64[3] array", "expected a list of 3 values")
    assert_problem(found, "fmus.c.start.i8", "300 is outside the range of an Int8 [-128, 127]")
    assert_problem(found, "fmus.c.start.u8", "-1 is outside the range of a UInt8 [0, 255]")
    assert_problem(found, "fmus.c.start.f32", "1e+300 is outside the range of a Float32", "inf")
    assert_problem(found, "fmus.d.start.i8", "101 is above the declared max 100 of 'i8'")
    assert_problem(found, "fmus.d.start.u8", "expected an integer value for a UInt8 variable, got float 2.5")
    assert_problem(found, "fmus.old.parameters.k", "1001.0 is above the declared max 1000 of 'k'")
    assert_problem(found, "fmus.old.start.n_steps", "2147483648 is outside the range of an Integer "
                                                    "[-2147483648, 2147483647]")
    assert not any(p.startswith("fmus.c.start.v_in") for p in found), found
    assert len(found) == 10, found


def test_values_at_the_ends_of_the_ranges_are_set_and_read_back_exactly(fmus, tmp_path):
    text = TIME + """
[record]
variables = ["c.u64", "c.i8", "c.u8", "c.f32", "c.ratio", "old.k"]

[fmus.c]
fmu = "Conformance3.fmu"
[fmus.c.parameters]
u64 = 18446744073709551615      # 2**64 - 1
ratio = 1.0
[fmus.c.start]
i8 = -100                       # the declared min
u8 = 255
f32 = 3.0e38                    # inside the Float32 range (max about 3.4e38)

[fmus.old]
fmu = "Integrator.fmu"
[fmus.old.parameters]
k = -1000.0
"""
    result, _ = run(scenario(tmp_path / "sc", text, fmus), tmp_path / "run")
    assert result.status == "completed", result.error
    got = columns(tmp_path / "run")
    assert set(got["c.u64"]) == {"18446744073709551615"}  # not 0, not a float
    assert set(got["c.i8"]) == {"-100"} and set(got["c.u8"]) == {"255"}
    assert {float(v) for v in got["c.f32"]} == {float(np.float32(3.0e38))}  # rounded to a single, not inf
    assert set(got["c.ratio"]) == {"1.0"} and set(got["old.k"]) == {"-1000.0"}


@pytest.mark.parametrize("source, target, value, reason", [
    # count = 300 gives count_out = 300 (Int32), which an Int8 cannot hold
    ("a.count_out", "b.i8", "count = 300", "i8: 300 is outside the range of an Int8 [-128, 127]"),
    # gain = 1e300, x = 1 gives y = 1e300 (Float64), which a Float32 cannot hold
    ("a.y", "b.f32", "x = 1.0", "f32: 1e+300 is outside the range of a Float32"),
])
def test_a_connected_value_out_of_the_targets_range_fails_the_run_naming_it(fmus, tmp_path, source, target,
                                                                          value, reason):
    text = f"""
connections = ["{source} -> {target}"]
""" + TIME + f"""
[fmus.a]
fmu = "Conformance3.fmu"
[fmus.a.parameters]
gain = 1e300
[fmus.a.start]
{value}

[fmus.b]
fmu = "Conformance3.fmu"
"""
    result, meta = run(scenario(tmp_path / "sc", text, fmus), tmp_path / "run")
    assert result.status == "failed"
    assert "instance 'b' failed in set values at t = 0 s" in result.error
    assert reason in result.error and "not set" in result.error
    assert meta["failed_instance"] == "b" and meta["failed_call"] == "set values"
    assert meta["steps_done"] == 0


# --------------------------------------------------- 2. connections during initialization
CHAIN = """
connections = ["a.y -> b.x", "b.y -> c.x"]

[time]
stop = 1.0
step = 0.1
ordering = "{ordering}"

[record]
variables = ["a.y", "b.x", "b.y", "c.x", "c.y"]

# declared last-to-first: the fixed point does not rely on file order
[fmus.c]
fmu = "Conformance3.fmu"
[fmus.c.parameters]
gain = 0.5

[fmus.b]
fmu = "Conformance3.fmu"
[fmus.b.parameters]
gain = 2.0

[fmus.a]
fmu = "Conformance3.fmu"
[fmus.a.parameters]
gain = 3.0
[fmus.a.start]
x = 2.0
"""


@pytest.mark.parametrize("ordering", ["jacobi", "gauss-seidel"])
def test_the_first_row_of_a_chain_is_consistent(fmus, tmp_path, ordering):
    # a.y = 3 * 2 = 6 -> b.x = 6 -> b.y = 2 * 6 = 12 -> c.x = 12 -> c.y = 0.5 * 12 = 6.
    # Before: the t = 0 row showed b.x = c.x = 0 (their start values) while a.y was already 6.
    result, meta = run(scenario(tmp_path / "sc", CHAIN.format(ordering=ordering), fmus), tmp_path / "run")
    assert result.status == "completed", result.error
    series = numbers(tmp_path / "run")
    first = {name: values[0] for name, values in series.items()}
    assert first == {"time": 0.0, "a.y": 6.0, "b.x": 6.0, "b.y": 12.0, "c.x": 12.0, "c.y": 6.0}
    # a's input never changes, so every later row is the same whatever the ordering
    for name, value in first.items():
        if name != "time":
            assert series[name] == [value] * 11, name
    # sweeps: b.x set (b.y changes), c.x set (c.y changes), then one in which nothing changed
    assert meta["initialization"] == {"connection_sweeps": 3}


def test_an_algebraic_loop_that_does_not_settle_is_named(fmus, tmp_path):
    # a.y = 2 a.x feeds b.x, b.y = 3 b.x feeds a.x: each sweep multiplies by 6, no fixed point but 0
    text = """
connections = ["a.y -> b.x", "b.y -> a.x"]
""" + TIME + """
[fmus.a]
fmu = "Conformance3.fmu"
[fmus.a.parameters]
gain = 2.0
[fmus.a.start]
x = 1.0

[fmus.b]
fmu = "Conformance3.fmu"
[fmus.b.parameters]
gain = 3.0
"""
    result, meta = run(scenario(tmp_path / "sc", text, fmus), tmp_path / "run")
    assert result.status == "failed"
    assert "failed in initialization at t = 0 s" in result.error
    assert "algebraic loop a.x -> a.y -> b.x -> b.y -> a.x" in result.error
    assert "did not settle in 4 sweeps" in result.error  # 2 connections + 2
    assert meta["failed_call"] == "initialization" and meta["steps_done"] == 0


def test_a_loop_through_an_output_without_feedthrough_initializes_and_runs(fmus, tmp_path):
    # a.x_int does not depend on a.x directly (it is a state): no algebraic loop.
    # a.x_int = 0.5 (start) -> b.x; b.y = 2 * 0.5 = 1 -> a.x. Each step: a.x_int += a.x * h.
    text = """
connections = ["a.x_int -> b.x", "b.y -> a.x"]
""" + TIME + """
[record]
variables = ["a.x_int", "a.x", "b.x", "b.y"]

[fmus.a]
fmu = "Conformance3.fmu"
[fmus.a.start]
x_int = 0.5

[fmus.b]
fmu = "Conformance3.fmu"
[fmus.b.parameters]
gain = 2.0
"""
    result, meta = run(scenario(tmp_path / "sc", text, fmus), tmp_path / "run")
    assert result.status == "completed", result.error
    series = numbers(tmp_path / "run")
    assert [series[n][0] for n in ("a.x_int", "b.x", "b.y", "a.x")] == [0.5, 0.5, 1.0, 1.0]
    # Jacobi, step 0: a.x = 1 (b.y at t0) -> a.x_int(0.1) = 0.5 + 1 * 0.1 = 0.6
    assert series["a.x_int"][1] == pytest.approx(0.6, abs=1e-12)


def test_feedthrough_loop_reads_dependencies_and_assumes_all_inputs_when_absent():
    from types import SimpleNamespace as NS

    from master.run.initialization import feedthrough_loop
    from master.scenario.loader import Connection

    def instance(outputs):
        inputs = [NS(name="u", causality="input"), NS(name="w", causality="input")]
        variables = inputs + [NS(name=name, causality="output") for name in outputs]
        by_name = {v.name: v for v in variables}
        unknowns = [NS(variable=by_name[name], dependencies=None if deps is None else [by_name[d] for d in deps])
                    for name, deps in outputs.items()]
        return NS(model_description=NS(modelVariables=variables, outputs=unknowns))

    loop = [Connection("p", "y", "q", "u"), Connection("q", "z", "p", "w")]
    # p.y depends on w only, q.z on nothing said (FMI: on every input): a loop p.w -> p.y -> q.u -> q.z -> p.w
    instances = {"p": instance({"y": ["w"]}), "q": instance({"z": None})}
    assert feedthrough_loop(instances, loop) == ["p.w", "p.y", "q.u", "q.z", "p.w"]
    # p.y depends on u only: the loop is broken inside p
    instances = {"p": instance({"y": ["u"]}), "q": instance({"z": None})}
    assert feedthrough_loop(instances, loop) is None


# -------------------------------------------------------------- 3. scheduled execution
def test_a_scheduled_execution_fmu_is_refused_by_its_interface(fmus, tmp_path, capsys):
    text = TIME + """
[fmus.clocked]
fmu = "Clocked3.fmu"
"""
    path = scenario(tmp_path / "sc", text, fmus)
    found = problems_of(path)
    assert found == [
        "fmus.clocked.fmu: Clocked3.fmu is an FMI 3 scheduled-execution FMU: its model partitions are activated "
        "by clocks the importer schedules, which this master does not support; it runs co-simulation FMUs"]
    assert not any("model exchange" in p for p in found)
    assert cli_main(["validate", str(path)]) == 2
    assert "scheduled-execution" in capsys.readouterr().err
    assert cli_main(["info", str(fmus["Clocked3"])]) == 0
    assert "(FMI 3.0; scheduled execution)" in capsys.readouterr().out


# ------------------------------------------------------------------------ 4. input files
INPUT_CSV = """time,x,level,count,on
0,0,1,0,0
0.25,1,2,3,1
0.5,1,2.5,-2,false
1.0,3,4,7,true
"""
# At the communication points t_k = 0, 0.1, ..., 1.0:
#   x (continuous Float64, linear): 4t up to 0.25, 1 up to 0.5, then 1 + 4 (t - 0.5)
X_AT = [0.0, 0.4, 0.8, 1.0, 1.0, 1.0, 1.4, 1.8, 2.2, 2.6, 3.0]
#   level (discrete Float64), count (Int32), on (Boolean): the last row at or before t (0.5 included)
LEVEL_AT = [1.0, 1.0, 1.0, 2.0, 2.0, 2.5, 2.5, 2.5, 2.5, 2.5, 4.0]
COUNT_AT = [0, 0, 0, 3, 3, -2, -2, -2, -2, -2, 7]
ON_AT = [0, 0, 0, 1, 1, 0, 0, 0, 0, 0, 1]


def as_recorded(at: list) -> list:
    """An input's recorded value at t_n is the value it held over the step that ended there, the one set
    at t_(n-1); at t_0 the one set during initialization. (The file's value at the stop time is never used.)"""
    return [at[0]] + at[:-1]


@pytest.mark.parametrize("form", ['input = "c_in.csv"', '[fmus.c.input]\nfile = "c_in.csv"'])
def test_an_input_file_drives_inputs_interpolated_or_held(fmus, tmp_path, form):
    text = TIME + f"""
[record]
variables = ["c.x", "c.y", "c.x_int", "c.level", "c.count", "c.count_out", "c.on", "c.on_out"]

[fmus.c]
fmu = "Conformance3.fmu"
{form}
[fmus.c.parameters]
gain = 2.0
"""
    path = scenario(tmp_path / "sc", text, fmus, {"c_in.csv": INPUT_CSV})
    sc = load_scenario(path)
    assert sc.resolved()["fmus"]["c"]["input"] == str(tmp_path / "sc" / "c_in.csv")
    result, meta = run(path, tmp_path / "run")
    assert result.status == "completed", result.error
    series = numbers(tmp_path / "run")
    assert series["time"] == pytest.approx(TIMES, abs=1e-12)
    assert series["c.x"] == pytest.approx(as_recorded(X_AT), abs=1e-12)
    assert series["c.y"] == pytest.approx([2 * x for x in as_recorded(X_AT)], abs=1e-12)
    assert series["c.level"] == as_recorded(LEVEL_AT)
    assert series["c.count"] == series["c.count_out"] == as_recorded(COUNT_AT)
    assert series["c.on"] == series["c.on_out"] == as_recorded(ON_AT)
    # x_int(t_n) = h * (x(t_0) + ... + x(t_(n-1))): 0, 0, 0.04, 0.12, 0.22, 0.32, 0.42, 0.56, 0.74, 0.96, 1.22
    assert series["c.x_int"] == pytest.approx([0, 0, 0.04, 0.12, 0.22, 0.32, 0.42, 0.56, 0.74, 0.96, 1.22],
                                              abs=1e-12)
    assert meta["input_files"]["c"] == {"file": str(tmp_path / "sc" / "c_in.csv"), "rows": 4,
                                        "interpolated": ["x"], "held": ["level", "count", "on"]}


def test_an_input_file_feeds_initialization_and_downstream_inputs(fmus, tmp_path):
    # the file's first row sets a.x = 5 before the t = 0 row; a.y = 5 feeds b.x through the connection
    text = """
connections = ["a.y -> b.x"]
""" + TIME + """
[record]
variables = ["a.x", "a.y", "b.x"]

[fmus.a]
fmu = "Conformance3.fmu"
input = "a_in.csv"

[fmus.b]
fmu = "Conformance3.fmu"
"""
    path = scenario(tmp_path / "sc", text, fmus, {"a_in.csv": "time,x\n0,5\n1,5\n"})
    result, _ = run(path, tmp_path / "run")
    assert result.status == "completed", result.error
    series = numbers(tmp_path / "run")
    assert [series[n][0] for n in ("a.x", "a.y", "b.x")] == [5.0, 5.0, 5.0]


def test_bad_input_files_are_refused_with_every_problem(fmus, tmp_path):
    text = """
connections = ["a.y -> c4.x"]
""" + TIME + """
[fmus.a]
fmu = "Conformance3.fmu"

[fmus.c1]
fmu = "Conformance3.fmu"
input = "columns.csv"

[fmus.c2]
fmu = "Conformance3.fmu"
input = "rows.csv"

[fmus.c3]
fmu = "Conformance3.fmu"
[fmus.c3.input]
file = "missing.csv"
interpolate = true

[fmus.c4]
fmu = "Conformance3.fmu"
input = "late.csv"

[fmus.c5]
fmu = "Conformance3.fmu"
input = 3
"""
    files = {  # rows.csv has a blank line 4: line numbers are the file's
        "columns.csv": "time,lvl,y,v_in\n0,1,2,3\n",
        "rows.csv": "time,x,count,i8,on\n0,0,1,0,0\n0.5,1,2.5,0,1\n\n0.5,2,3,0,1\n0.75,2,3,300,yes\n",
        "late.csv": "time,x\n0.2,1\n0.4,2\n",
    }
    found = problems_of(scenario(tmp_path / "sc", text, fmus, files))
    assert_problem(found, "fmus.c1.input", "columns.csv: unknown column 'lvl'", "did you mean 'level'?")
    assert_problem(found, "fmus.c1.input", "column 'y': y is an output, only inputs can be driven from a file")
    assert_problem(found, "fmus.c1.input", "column 'v_in'", "Float64[3] array", "scalar inputs only")
    assert_problem(found, "fmus.c2.input", "rows.csv line 3, column 'count': expected an integer for Int32 count, "
                                           "got '2.5'")
    assert_problem(found, "fmus.c2.input", "rows.csv line 5: time 0.5 is not after the previous row's 0.5",
                   "increasing")
    assert_problem(found, "fmus.c2.input", "rows.csv line 6, column 'i8': 300 is outside the range of an Int8")
    assert_problem(found, "fmus.c2.input", "rows.csv line 6, column 'on': expected a Boolean", "'yes'")
    assert_problem(found, "fmus.c3.input.file", "cannot read", "missing.csv")
    assert_problem(found, "fmus.c3.input.interpolate", "unknown key (expected one of: file)")
    assert_problem(found, "fmus.c4.input", "late.csv starts at t = 0.2 s, after time.start = 0 s")
    assert_problem(found, "fmus.c5.input", "expected the path of a CSV file", "got 3")
    assert len(found) == 11, found


def test_an_input_driven_by_a_file_cannot_also_be_connected(fmus, tmp_path):
    text = """
connections = ["a.y -> c.x"]
""" + TIME + """
[fmus.a]
fmu = "Conformance3.fmu"

[fmus.c]
fmu = "Conformance3.fmu"
input = "c_in.csv"
"""
    found = problems_of(scenario(tmp_path / "sc", text, fmus, {"c_in.csv": "time,x\n0,1\n"}))
    assert found == ["connections[0]: c.x is already driven by the input file c_in.csv"]


def test_input_table_holds_at_a_row_reached_a_rounding_error_early():
    from master.scenario.input_file import InputColumn, InputTable

    table = InputTable(Path("t.csv"), [0.0, 0.3, 1.0], [InputColumn("n", [1, 2, 3], interpolate=False),
                                                      InputColumn("x", [0.0, 3.0, 3.0], interpolate=True)])
    # 0.1 * 3 is 0.30000000000000004, but 0.29999999999999993 (e.g. 0.7 - 0.4) is the same communication point
    assert table.values_at(0.29999999999999993) == {"n": 2, "x": pytest.approx(3.0, abs=1e-12)}
    assert table.values_at(0.29) == {"n": 1, "x": pytest.approx(2.9, abs=1e-12)}
    assert table.values_at(5.0) == {"n": 3, "x": 3.0}  # after the last row: the last values hold


# ------------------------------------------------------------------------ 5. FMI 3 arrays
ARRAYS = """
connections = ["a.v_out -> b.v_in"]
""" + TIME + """
[record]
variables = ["a.*", "b.v_in", "b.v_out"]

[fmus.a]
fmu = "Conformance3.fmu"
[fmus.a.parameters]
gain = 2.0
offsets = [1.0, 2.0, 3.0]
[fmus.a.start]
v_in = [1.0, 2.0, 3.0]

[fmus.b]
fmu = "Conformance3.fmu"
[fmus.b.parameters]
offsets = [0.0, 0.0, -10.0]
"""


def test_arrays_are_recorded_element_by_element_and_connected(fmus, tmp_path):
    # a.v_out = 2 * [1, 2, 3] + [1, 2, 3] = [3, 6, 9]; a.v_sum = 6
    # b.v_in = a.v_out = [3, 6, 9] (from t = 0: propagated in initialization); b.v_out = b.v_in + [0, 0, -10]
    result, _ = run(scenario(tmp_path / "sc", ARRAYS, fmus), tmp_path / "run")
    assert result.status == "completed", result.error
    series = numbers(tmp_path / "run")
    assert list(series) == ["time", "a.y", "a.x_int", "a.count_out", "a.on_out",
                            "a.v_out[1]", "a.v_out[2]", "a.v_out[3]", "a.v_sum",
                            "b.v_in[1]", "b.v_in[2]", "b.v_in[3]", "b.v_out[1]", "b.v_out[2]", "b.v_out[3]"]
    expected = {"a.v_out[1]": 3.0, "a.v_out[2]": 6.0, "a.v_out[3]": 9.0, "a.v_sum": 6.0,
                "b.v_in[1]": 3.0, "b.v_in[2]": 6.0, "b.v_in[3]": 9.0,
                "b.v_out[1]": 3.0, "b.v_out[2]": 6.0, "b.v_out[3]": -1.0}
    for column, value in expected.items():
        assert series[column] == [value] * 11, column


def test_array_connections_need_the_same_size(fmus, tmp_path):
    text = ARRAYS.replace('["a.v_out -> b.v_in"]', '["a.v_out -> b.w_in", "a.y -> b.v_in", "a.v_out -> b.x"]')
    found = problems_of(scenario(tmp_path / "sc", text, fmus))
    assert found == ["connections[0]: size mismatch: a.v_out is Float64[3], b.w_in is Float64[2]",
                     "connections[1]: size mismatch: a.y is Float64, b.v_in is Float64[3]",
                     "connections[2]: size mismatch: a.v_out is Float64[3], b.x is Float64"]


def test_info_shows_array_sizes(fmus, capsys):
    assert cli_main(["info", str(fmus["Conformance3"])]) == 0
    types = {line.split()[0]: line.split()[3] for line in capsys.readouterr().out.splitlines()[3:]}
    assert types["v_in"] == "Float64[3]" and types["w_in"] == "Float64[2]" and types["x"] == "Float64"


def test_array_helpers_name_elements_row_major_and_flatten_nested_lists():
    from master.fmi.variables import element_names, flatten

    assert element_names("m", ()) == ["m"]
    assert element_names("m", (2, 3)) == ["m[1,1]", "m[1,2]", "m[1,3]", "m[2,1]", "m[2,2]", "m[2,3]"]
    assert flatten([[1, 2, 3], [4, 5, 6]], (2, 3)) == [1, 2, 3, 4, 5, 6]
    assert flatten([1, 2, 3, 4, 5, 6], (2, 3)) == [1, 2, 3, 4, 5, 6]  # flat, as FMI 3 passes arrays
    assert flatten([[1, 2], [3, 4]], (2, 3)) is None
    assert flatten([1, 2], (3,)) is None and flatten(1.0, (3,)) is None


def test_a_stop_condition_takes_an_arrays_scalar_outputs_not_the_array(fmus, tmp_path):
    # a condition compares numbers: v_sum (a scalar) is a signal, v_out (a Float64[3]) is not
    text = ARRAYS.replace("step = 0.1", 'step = 0.1\nstop_on = ["a.v_out > 1", "a.v_sum > 100"]')
    found = problems_of(scenario(tmp_path / "sc", text, fmus))
    assert len(found) == 1 and found[0].startswith("time.stop_on[0]: 'a.v_out > 1': unknown signal 'a.v_out'")
