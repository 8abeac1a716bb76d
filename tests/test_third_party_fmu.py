"""The master runs third-party FMUs: binary FMI 2.0 and FMI 3.0 co-simulation
FMUs compiled from C during the test, not the project's pythonfmu FMUs.

The FMUs (tests/third_party_fmu/, built by its build.py against fmpy's FMI
headers) integrate dy/dt = k*u explicitly over each communication step h:

    y(t + h) = y(t) + k * u * h,  n_steps += 1

and fail in doStep (error status plus an error log message "fail_at
reached ...") at every communication point t >= fail_at when fail_at >= 0.
With stop_at >= 0 the step that reaches stop_at completes and ends the
simulation (FMI 2: fmi2Discard + fmi2Terminated; FMI 3: terminateSimulation).
The Boolean output `odd` is n_steps odd. The FMI 2 one also has a String
output `label` ("step <n_steps>"), a String input `label_in` that it keeps and
returns, and `discard_at` (doStep returns fmi2Discard without terminating).

Hand-computed references used below (h = 0.1 s, 10 steps):
  * one instance, k = 3, u = 2:      y(t) = 6 t, so y(1) = 6.0, n_steps = 10.
  * a (k = 2, u = 1) -> b.u, b k = 1: a.y(t_j) = 0.2 j.
      Jacobi: b's step j (t_j -> t_j+1) sees a.y(t_j), a's output at the
        previous communication point:
        b.y(t_n) = sum_{j<n} 0.2 j * 0.1 = 0.01 n (n-1)
      Gauss-Seidel (a declared first): b's step j sees a.y(t_j+1), the value
        a produced in the same step:
        b.y(t_n) = sum_{j<n} 0.2 (j+1) * 0.1 = 0.01 n (n+1)
      difference GS - Jacobi = 0.02 n, i.e. 0.2 at t = 1 s.
"""
from __future__ import annotations

import csv
import importlib.util
import json
import shutil
import sys
import zipfile
from pathlib import Path

import pytest

from master.cli import main as cli_main
from master.run.cosim import CoSimulation
from master.hooks import Hook
from master.scenario.loader import load_scenario

FMU_SOURCES = Path(__file__).resolve().parent / "third_party_fmu"
H = 0.1
TIMES = [round(H * n, 10) for n in range(11)]  # 0.0 .. 1.0

# b.y of the coupled scenario, computed by hand (see the module docstring)
B_Y_JACOBI = [0.0, 0.0, 0.02, 0.06, 0.12, 0.20, 0.30, 0.42, 0.56, 0.72, 0.90]
B_Y_GAUSS_SEIDEL = [0.0, 0.02, 0.06, 0.12, 0.20, 0.30, 0.42, 0.56, 0.72, 0.90, 1.10]


def c_fmu_builder():
    """tests/third_party_fmu/build.py as a module, or a skip with the reason the C test FMUs cannot be built."""
    spec = importlib.util.spec_from_file_location("third_party_fmu_build", FMU_SOURCES / "build.py")
    build = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = build  # its dataclasses look their module up while it loads
    spec.loader.exec_module(build)
    if sys.platform == "win32":
        pytest.skip("the C test FMUs are built with gcc for Linux/macOS only")
    if build.compiler() is None:
        pytest.skip("gcc not found: cannot compile the C test FMUs in tests/third_party_fmu/")
    return build


@pytest.fixture(scope="session")
def third_party_fmus(tmp_path_factory) -> dict[int, Path]:
    """{2: Integrator.fmu, 3: Integrator3.fmu}, compiled once per session."""
    build = c_fmu_builder()
    return build.build_all(tmp_path_factory.mktemp("third_party_fmus"))


@pytest.fixture
def fmu2(third_party_fmus) -> Path:
    return third_party_fmus[2]


@pytest.fixture
def fmu3(third_party_fmus) -> Path:
    return third_party_fmus[3]


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def integrator(request, third_party_fmus) -> Path:
    """The Integrator model, once as FMI 2.0 and once as FMI 3.0."""
    return third_party_fmus[request.param]


# ---------------------------------------------------------------- helpers
def write_scenario(directory: Path, name: str, text: str, fmus: list[Path]) -> Path:
    """A scenario file next to copies of its FMUs (referenced by relative path)."""
    directory.mkdir(parents=True, exist_ok=True)
    for fmu in fmus:
        if not (directory / fmu.name).exists():
            shutil.copy(fmu, directory / fmu.name)
    path = directory / f"{name}.toml"
    path.write_text(text)
    return path


def read_series(run_dir: Path) -> dict[str, list[float]]:
    with open(run_dir / "timeseries.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows, "timeseries.csv has no rows"
    return {column: [float(r[column]) for r in rows] for column in rows[0]}


def run(path: Path, run_dir: Path):
    result = CoSimulation(load_scenario(path), run_dir, quiet=True).run()
    meta = json.loads((run_dir / "metadata.json").read_text())
    return result, read_series(run_dir), meta


def single_scenario(fmu: Path, **parameters) -> str:
    params = "\n".join(f"{k} = {v!r}" for k, v in {"k": 3.0, **parameters}.items())
    return f"""
[time]
stop = 1.0
step = 0.1

[fmus.integ]
fmu = "{fmu.name}"

[fmus.integ.parameters]
{params}

[fmus.integ.start]
u = 2.0
"""


def coupled_scenario(fmu_a: Path, fmu_b: Path, ordering: str) -> str:
    return f"""
connections = ["a.y -> b.u"]

[time]
stop = 1.0
step = 0.1
ordering = "{ordering}"

[fmus.a]
fmu = "{fmu_a.name}"
[fmus.a.parameters]
k = 2.0
[fmus.a.start]
u = 1.0

[fmus.b]
fmu = "{fmu_b.name}"
[fmus.b.parameters]
k = 1.0
"""


# ------------------------------------------------------------ the FMUs
def test_fmi2_fmu_is_a_native_binary_and_validates_clean(fmu2):
    import fmpy
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    with zipfile.ZipFile(fmu2) as zf:
        names = set(zf.namelist())
    assert names == {"modelDescription.xml",
                     f"binaries/{fmpy.platform}/Integrator{fmpy.sharedLibraryExtension}"}
    assert validate_fmu(str(fmu2)) == []
    md = read_model_description(str(fmu2))
    assert md.fmiVersion == "2.0"
    assert md.coSimulation.modelIdentifier == "Integrator" and md.modelExchange is None


def test_fmi3_fmu_validates_clean(fmu3):
    # fmpy 0.3.32 validates FMI 3 too: the XML schema, variable names, the
    # model structure, start values, causality/variability combinations
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmu3)) == []
    md = read_model_description(str(fmu3))
    assert md.fmiVersion == "3.0"
    assert md.coSimulation.modelIdentifier == "Integrator3" and md.modelExchange is None


def test_fmi3_fmu_runs_with_fmpy_FMU3Slave_directly(fmu3, tmp_path):
    # The FMU on its own, through fmpy only: a reference independent of the master.
    from fmpy import extract, read_model_description
    from fmpy.fmi3 import FMU3Model, FMU3Slave

    md = read_model_description(str(fmu3))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzipped = extract(str(fmu3), unzipdir=str(tmp_path / "unzipped"))
    slave = FMU3Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="Integrator3", instanceName="s")
    slave.instantiate()
    slave.enterInitializationMode(startTime=0.0, stopTime=1.0)
    slave.setFloat64([vr["k"], vr["u"]], [3.0, 2.0])
    slave.exitInitializationMode()
    for n in range(10):
        event, terminate, early, last = slave.doStep(n * H, H)
        assert (event, terminate, early) == (False, False, False)
        assert last == pytest.approx((n + 1) * H, abs=1e-12)
    assert slave.getFloat64([vr["y"]])[0] == pytest.approx(6.0, rel=1e-12)
    assert slave.getInt32([vr["n_steps"]]) == [10]
    slave.terminate()
    slave.freeInstance()

    # co-simulation only: fmi3InstantiateModelExchange returns NULL
    model = FMU3Model(guid=md.guid, unzipDirectory=unzipped, modelIdentifier="Integrator3", instanceName="m")
    with pytest.raises(Exception, match="Failed to instantiate"):
        model.instantiate()


@pytest.mark.parametrize("version", [2, 3])
def test_info_lists_variables_with_causality(third_party_fmus, version, capsys):
    assert cli_main(["info", str(third_party_fmus[version])]) == 0
    out = capsys.readouterr().out
    assert f"(FMI {version}.0; co-simulation)" in out
    table = {}
    for line in out.splitlines():
        cells = line.split()
        if len(cells) >= 2:
            table.setdefault(cells[0], cells[1])
    assert table["u"] == "input"
    assert table["k"] == "parameter"
    assert table["y"] == "output"
    assert table["fail_at"] == "parameter"
    assert table["n_steps"] == "output"


# ---------------------------------------------------------- through the master
def test_single_instance_integrates_k_u(integrator, tmp_path):
    path = write_scenario(tmp_path / "sc", "single", single_scenario(integrator), [integrator])
    result, series, meta = run(path, tmp_path / "run")

    assert result.status == "completed", result.error
    assert series["time"] == pytest.approx(TIMES, abs=1e-12)
    # y(t) = k*u*t = 6 t at every communication point, 6.0 at t = 1 s
    assert series["integ.y"] == pytest.approx([6.0 * t for t in TIMES], abs=1e-12)
    assert series["integ.y"][-1] == pytest.approx(6.0, rel=1e-12)
    assert series["integ.n_steps"] == list(range(11))
    md = load_scenario(path).instances["integ"].model_description
    assert meta["instances"]["integ"]["fmi_version"] == md.fmiVersion
    assert meta["instances"]["integ"]["model_identifier"] == md.coSimulation.modelIdentifier
    assert meta["status"] == "completed" and meta["steps_done"] == 10


def test_two_instances_jacobi_versus_gauss_seidel(integrator, tmp_path):
    jacobi, series_j, meta_j = run(
        write_scenario(tmp_path / "sc", "jacobi", coupled_scenario(integrator, integrator, "jacobi"), [integrator]),
        tmp_path / "run-jacobi")
    gs, series_gs, meta_gs = run(
        write_scenario(tmp_path / "sc", "gs", coupled_scenario(integrator, integrator, "gauss-seidel"), [integrator]),
        tmp_path / "run-gs")
    assert jacobi.status == "completed", jacobi.error
    assert gs.status == "completed", gs.error

    # a has no inputs: the same in both orderings
    for series in (series_j, series_gs):
        assert series["time"] == pytest.approx(TIMES, abs=1e-12)
        assert series["a.y"] == pytest.approx([0.2 * n for n in range(11)], abs=1e-12)
        assert series["b.n_steps"] == list(range(11))

    assert series_j["b.y"] == pytest.approx(B_Y_JACOBI, abs=1e-12)
    assert series_gs["b.y"] == pytest.approx(B_Y_GAUSS_SEIDEL, abs=1e-12)
    # Gauss-Seidel is ahead by one step of a's output: 0.02 n, 0.2 at t = 1 s
    diff = [g - j for g, j in zip(series_gs["b.y"], series_j["b.y"])]
    assert diff == pytest.approx([0.02 * n for n in range(11)], abs=1e-12)
    assert diff[-1] == pytest.approx(0.2, abs=1e-12)

    assert meta_j["connection_delays"] == [{"connection": "a.y -> b.u", "delay_s": H}]
    assert meta_gs["connection_delays"] == [{"connection": "a.y -> b.u", "delay_s": 0.0}]


def test_fail_at_ends_the_run_with_the_fmu_error(integrator, tmp_path):
    path = write_scenario(tmp_path / "sc", "fail", single_scenario(integrator, fail_at=0.5), [integrator])
    result, series, meta = run(path, tmp_path / "run")

    assert result.status == "failed"
    assert "'integ'" in result.error
    assert "doStep" in result.error
    assert "t = 0.5 s" in result.error
    assert "fail_at reached" in result.error  # the FMU's own log text
    # rows up to t = 0.5 (the last completed step), none after
    assert series["time"] == pytest.approx(TIMES[:6], abs=1e-12)
    assert series["integ.y"] == pytest.approx([6.0 * t for t in TIMES[:6]], abs=1e-12)
    assert series["integ.n_steps"] == list(range(6))
    assert meta["status"] == "failed"
    assert meta["failed_instance"] == "integ"
    assert meta["failed_time_s"] == pytest.approx(0.5, abs=1e-12)
    assert meta["failed_call"] == "doStep"
    assert meta["steps_done"] == 5


def test_cli_run_exit_codes(fmu2, tmp_path, capsys):
    ok = write_scenario(tmp_path / "sc", "ok", single_scenario(fmu2), [fmu2])
    bad = write_scenario(tmp_path / "sc", "bad", single_scenario(fmu2, fail_at=0.5), [fmu2])

    assert cli_main(["run", str(ok), "--out", str(tmp_path / "run-ok"), "--quiet"]) == 0
    assert read_series(tmp_path / "run-ok")["integ.y"][-1] == pytest.approx(6.0, rel=1e-12)

    capsys.readouterr()
    assert cli_main(["run", str(bad), "--out", str(tmp_path / "run-bad"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "fail_at reached" in err and "'integ'" in err


def test_fmi3_gives_the_same_result_as_fmi2(fmu2, fmu3, tmp_path):
    results = {}
    for fmu in (fmu2, fmu3):
        path = write_scenario(tmp_path / "sc", fmu.stem, single_scenario(fmu), [fmu])
        result, series, _ = run(path, tmp_path / f"run-{fmu.stem}")
        assert result.status == "completed", result.error
        results[fmu.stem] = series
    # the same arithmetic in both binaries: identical, not merely close
    assert results["Integrator3"] == results["Integrator"]
    assert results["Integrator3"]["integ.y"][-1] == pytest.approx(6.0, rel=1e-12)


def test_fmi2_output_drives_fmi3_input(fmu2, fmu3, tmp_path):
    # mixed versions in one scenario: an FMI 2 Real output into an FMI 3 Float64 input
    path = write_scenario(tmp_path / "sc", "mixed", coupled_scenario(fmu2, fmu3, "gauss-seidel"), [fmu2, fmu3])
    result, series, meta = run(path, tmp_path / "run")
    assert result.status == "completed", result.error
    assert [meta["instances"][i]["fmi_version"] for i in ("a", "b")] == ["2.0", "3.0"]
    assert series["b.y"] == pytest.approx(B_Y_GAUSS_SEIDEL, abs=1e-12)


# ------------------------------------------------ conformance (issue 19)
class Probe(Hook):
    """An observer after the recorder: what hooks see after each step (values read from the FMUs)."""

    name = "probe"

    def __init__(self, instance: str, variables: list[str]):
        self.instance, self.variables = instance, variables
        self.seen: list[tuple[float, dict]] = []

    def open(self, ctx):
        self.fmu = ctx.members[self.instance].fmu

    def after_step(self, k, t_next):
        self.seen.append((t_next, self.fmu.get_by_name(self.variables)))


def raw_column(run_dir: Path, column: str) -> list[str]:
    with open(run_dir / "timeseries.csv", newline="") as f:
        return [row[column] for row in csv.DictReader(f)]


def test_fmu_that_ends_the_simulation_stops_the_run_cleanly(integrator, tmp_path, capsys):
    # the step to t = 0.5 ends the simulation: recorded, then the run stops (exit 0)
    path = write_scenario(tmp_path / "sc", "stop", single_scenario(integrator, stop_at=0.5), [integrator])
    assert cli_main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 0

    meta = json.loads((tmp_path / "run" / "metadata.json").read_text())
    assert meta["status"] == "stopped" and meta["error"] is None
    assert meta["stop_reason"] == "terminated by instance 'integ' at t = 0.5 s"
    assert meta["steps_done"] == 5
    series = read_series(tmp_path / "run")
    assert series["time"] == pytest.approx(TIMES[:6], abs=1e-12)
    assert series["time"][-1] == pytest.approx(0.5, abs=1e-12)
    assert series["integ.y"][-1] == pytest.approx(3.0, rel=1e-12)  # y = 6 t at t = 0.5
    assert series["integ.n_steps"][-1] == 5


def test_every_hook_sees_the_step_that_ended_the_simulation(integrator, tmp_path):
    path = write_scenario(tmp_path / "sc", "stop", single_scenario(integrator, stop_at=0.5), [integrator])
    cosim = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True)
    probe = Probe("integ", ["y"])
    cosim.extra_hooks.append(probe)
    result = cosim.run()
    assert result.status == "stopped", result.error
    assert [t for t, _ in probe.seen] == pytest.approx(TIMES[1:6], abs=1e-12)
    assert probe.seen[-1][1]["y"] == pytest.approx(3.0, rel=1e-12)


def test_other_discards_stay_errors_naming_the_instance(fmu2, tmp_path):
    path = write_scenario(tmp_path / "sc", "discard", single_scenario(fmu2, discard_at=0.5), [fmu2])
    result, series, meta = run(path, tmp_path / "run")
    assert result.status == "failed"
    assert "instance 'integ' failed in doStep at t = 0.5 s" in result.error
    assert "discard_at reached" in result.error  # the FMU's own log text
    assert meta["failed_instance"] == "integ" and meta["failed_call"] == "doStep"
    assert "stop_reason" not in meta
    assert series["time"] == pytest.approx(TIMES[:6], abs=1e-12)


@pytest.mark.parametrize("ordering, first", [("jacobi", 0), ("gauss-seidel", 1)])
def test_fmi2_string_output_reaches_a_string_input(fmu2, tmp_path, ordering, first):
    # fmpy's FMI 2 getString gives bytes; the master hands text on (and setString needs str)
    text = coupled_scenario(fmu2, fmu2, ordering).replace(
        'connections = ["a.y -> b.u"]', 'connections = ["a.y -> b.u", "a.label -> b.label_in"]')
    path = write_scenario(tmp_path / "sc", ordering, text, [fmu2])
    cosim = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True)
    probe = Probe("b", ["label_in"])
    cosim.extra_hooks.append(probe)
    result = cosim.run()
    assert result.status == "completed", result.error
    received = [seen["label_in"] for _, seen in probe.seen]
    # jacobi: b's step from t_n gets a's label at t_n ("step n"); gauss-seidel: after a's step ("step n+1")
    assert received == [f"step {n + first}" for n in range(10)]
    assert all(type(v) is str for v in received)
    assert "a.label" not in read_series(tmp_path / "run")  # Strings are not recorded


def test_booleans_are_recorded_as_1_0_for_fmi2_and_fmi3(integrator, tmp_path):
    path = write_scenario(tmp_path / "sc", "bool", single_scenario(integrator), [integrator])
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    # odd = n_steps is odd: the same text in the CSV whatever the FMI version
    assert raw_column(tmp_path / "run", "integ.odd") == ["0", "1"] * 5 + ["0"]
