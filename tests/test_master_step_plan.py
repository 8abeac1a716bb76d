"""The master's stepping loop as a plan (master.run.algorithm.step_plan) and the recorder's block formatting
(master.run.recorder): per-FMU costs left the loop (issue 19); the results, the calls and the errors must not change.

Pure core first: FmuInstance over a fake fmpy slave (no FMU binary), the plan compared call by call with
the step-by-step algorithm it replaced (written out below as the reference), and its errors with the ones
FmuInstance's own checked calls raise for the same failure. Then the recorder's text against the csv
module's, and one run of the compiled test FMU where an instance in the middle ends the simulation.
"""
from __future__ import annotations

import csv
import importlib.util
import io
import json
import shutil
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from master.run.algorithm import step_plan
from master.errors import SimulationError
from master.fmi.runtime import FmuInstance
from master.hooks import Member
from master.run.recorder import FLUSH_S, TIMESERIES, RunRecorder

H = 0.1


class FakeStatus(Exception):
    """fmpy's FMICallException as the master sees it: a message and the FMI status."""

    def __init__(self, call: str, status: int):
        super().__init__(f"{call} failed with status {status}")
        self.status = status


class FakeSlave:
    """An fmpy FMU2Slave as the master calls it; every call goes to the shared `calls` log, in order.

    y integrates u (y += u * h, plus h so that it moves unconnected), n counts the steps.
    """

    def __init__(self, name: str, calls: list):
        self.name, self.calls = name, calls
        self.u, self.y, self.n = 1.0, 0.0, 0
        self.fail_step_at = self.terminate_at = self.fail_get_at = None
        self.terminated = False

    def doStep(self, t, h, noSetFMUStatePriorToCurrentPoint=True):
        self.calls.append((self.name, "doStep", round(t, 9), h))
        if self.fail_step_at is not None and t >= self.fail_step_at - 1e-9:
            raise FakeStatus("fmi2DoStep", 3)
        self.y += (self.u + 1.0) * h
        self.n += 1
        if self.terminate_at is not None and t + h >= self.terminate_at - 1e-9:
            self.terminated = True
            raise FakeStatus("fmi2DoStep", 2)  # fmi2Discard + fmi2Terminated: the FMU ends the simulation

    def getBooleanStatus(self, kind):
        return self.terminated

    def getReal(self, vrs):
        self.calls.append((self.name, "getReal", tuple(vrs)))
        return [self.y for _ in vrs]

    def getInteger(self, vrs):
        self.calls.append((self.name, "getInteger", tuple(vrs)))
        if self.fail_get_at is not None and self.n >= self.fail_get_at:
            raise FakeStatus("fmi2GetInteger", 3)
        return [self.n for _ in vrs]

    def setReal(self, vrs, values):
        self.calls.append((self.name, "setReal", tuple(vrs), tuple(values)))
        self.u = values[0]


VARIABLES = [SimpleNamespace(name="y", type="Real", valueReference=0, causality="output"),
             SimpleNamespace(name="n", type="Integer", valueReference=1, causality="output"),
             SimpleNamespace(name="u", type="Real", valueReference=2, causality="input")]


def bound(names: list[str], calls: list, multiples: dict[str, int] | None = None,
          connections: tuple[tuple[str, str], ...] = ()) -> tuple[list[Member], list]:
    """Members over fake slaves, bound as master.run.cosim binds them: y and n of each in one flat table
    (two getter groups per instance), and each (src, dst) connection src.y -> dst.u."""
    members, slot = [], 0
    for name in names:
        fmu = FmuInstance(name, SimpleNamespace(fmiVersion="2.0", modelVariables=VARIABLES), "")
        fmu._slave = FakeSlave(name, calls)
        m = Member(fmu, (multiples or {}).get(name, 1))
        m.outputs += [(fmu.accessor("real", [0], setter=False), slot, slot + 1),
                      (fmu.accessor("integer", [1], setter=False), slot + 1, slot + 2)]
        members.append(m)
        slot += 2
    by_name = {m.fmu.name: m for m in members}
    for src, dst in connections:
        first = names.index(src) * 2
        by_name[dst].inputs.append((by_name[dst].fmu.accessor("real", [2], setter=True), [first]))
    return members, [0.0] * slot


def reference_step(ordering: str, k: int, t: float, h: float, members: list[Member], values: list) -> None:
    """The step-by-step algorithm the plan replaced: per member and step, the checked wrappers."""
    def set_inputs(m):
        for setter, slots in m.inputs:
            setter([values[s] for s in slots])

    def read_outputs(ms):
        for m in ms:
            for getter, first, end in m.outputs:
                values[first:end] = getter()

    if ordering == "jacobi":
        due = [m for m in members if k % m.multiple == 0]
        for m in due:
            set_inputs(m)
        for m in due:
            m.fmu.do_step(t, m.multiple * h)
        read_outputs(due)
    else:
        for m in members:
            if k % m.multiple == 0:
                set_inputs(m)
                m.fmu.do_step(t, m.multiple * h)
                read_outputs((m,))


@pytest.mark.parametrize("ordering", ["jacobi", "gauss-seidel"])
@pytest.mark.parametrize("multiples", [{}, {"b": 2, "c": 3}], ids=["every step", "multi-rate"])
def test_the_plan_makes_the_calls_and_values_of_the_step_by_step_algorithm(ordering, multiples):
    names, connections = ["a", "b", "c"], (("a", "b"), ("c", "a"))
    ref_calls, plan_calls = [], []
    ref_members, ref_values = bound(names, ref_calls, multiples, connections)
    members, values = bound(names, plan_calls, multiples, connections)
    table = values
    step = step_plan(ordering, members, values, H)
    for k in range(13):  # two periods of the multi-rate case, and one step more
        t = k * H
        reference_step(ordering, k, t, H, ref_members, ref_values)
        step(k, t)
        assert plan_calls == ref_calls, f"step {k}"
        assert values == ref_values, f"step {k}"
        assert [m.fmu.time for m in members] == [m.fmu.time for m in ref_members]
    assert values is table  # hooks hold the table: filled in place
    assert {c[1] for c in plan_calls} == {"doStep", "getReal", "getInteger", "setReal"}
    assert values != [0.0] * len(values)


def test_an_unknown_ordering_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown ordering 'jacobbi'.*jacobi, gauss-seidel"):
        step_plan("jacobbi", [], [], H)


def twin_error(names: list[str], failing: str, setup, call) -> str:
    """The message FmuInstance's own checked call raises for the same failure (the behaviour to keep)."""
    members, _ = bound(names, [])
    fmu = next(m.fmu for m in members if m.fmu.name == failing)
    setup(fmu._slave)
    with pytest.raises(SimulationError) as exc:
        call(fmu, members)
    return str(exc.value)


@pytest.mark.parametrize("ordering", ["jacobi", "gauss-seidel"])
def test_a_failed_doStep_names_its_instance_and_the_later_ones_do_not_step(ordering):
    calls = []
    members, values = bound(["a", "b", "c"], calls)
    members[1].fmu._slave.fail_step_at = 0.2
    step = step_plan(ordering, members, values, H)
    step(0, 0.0)
    step(1, H)
    calls.clear()
    with pytest.raises(SimulationError) as exc:
        step(2, 2 * H)
    err = exc.value
    assert (err.instance, err.call, err.time) == ("b", "doStep", pytest.approx(0.2))
    assert str(err) == twin_error(["a", "b", "c"], "b", lambda s: setattr(s, "fail_step_at", 0.2),
                                  lambda fmu, _: fmu.do_step(2 * H, H))
    assert "instance 'b' failed in doStep at t = 0.2 s: fmi2DoStep failed with status 3" == str(err)
    assert ("c", "doStep", 0.2, H) not in calls
    assert members[1].fmu.failed == "error"  # freed, not terminated (FMI after an error status)


@pytest.mark.parametrize("ordering", ["jacobi", "gauss-seidel"])
def test_an_fmu_that_ends_the_simulation_lets_the_others_finish_the_step(ordering):
    calls = []
    members, values = bound(["a", "b", "c"], calls)
    members[1].fmu._slave.terminate_at = 0.3
    reasons = []
    for m in members:
        m.fmu.on_terminate = reasons.append
    step = step_plan(ordering, members, values, H)
    for k in range(3):
        step(k, k * H)
    assert reasons == ["terminated by instance 'b' at t = 0.3 s"]
    assert ("c", "doStep", 0.2, H) in calls  # after b in the list, still stepped
    assert values == [pytest.approx(0.6), 3] * 3  # and every output read after the step
    assert members[1].fmu.terminated_at == pytest.approx(0.3)


def test_an_fmu_ending_the_simulation_with_no_master_listening_is_an_error():
    members, values = bound(["a", "b"], [])
    members[0].fmu._slave.terminate_at = 0.1
    with pytest.raises(SimulationError, match="terminated by instance 'a' at t = 0.1 s, but no master listens"):
        step_plan("jacobi", members, values, H)(0, 0.0)


@pytest.mark.parametrize("ordering, names", [("jacobi", ["a", "b", "c"]), ("gauss-seidel", ["a", "b", "c"]),
                                             ("jacobi", ["b"])], ids=["jacobi", "gauss-seidel", "one instance"])
def test_a_failed_read_names_the_instance_whose_getter_failed(ordering, names):
    members, values = bound(names, [])
    failing = next(m for m in members if m.fmu.name == "b")
    failing.fmu._slave.fail_get_at = 2
    step = step_plan(ordering, members, values, H)
    step(0, 0.0)
    with pytest.raises(SimulationError) as exc:
        step(1, H)
    err = exc.value
    assert (err.instance, err.call, err.time) == ("b", "get values", pytest.approx(0.1))

    def checked_read(fmu, twin_members):
        fmu.do_step(0.0, H)
        fmu.do_step(H, H)
        twin = next(m for m in twin_members if m.fmu is fmu)
        twin.outputs[1][0]()  # the checked getter of n, as hooks and the first row call it
    assert str(err) == twin_error(names, "b", lambda s: setattr(s, "fail_get_at", 2), checked_read)
    assert str(err) == "instance 'b' failed in get values at t = 0.1 s: fmi2GetInteger failed with status 3"


def test_the_checked_getter_and_its_read_call_give_the_same_values():
    members, _ = bound(["a"], [])
    fmu = members[0].fmu
    fmu.do_step(0.0, H)
    for getter, _first, _end in members[0].outputs:
        read, arg = getter.read_call
        assert getter() == read(arg) and read.__self__ is fmu._slave  # fmpy's own getter, no wrapper of ours


def test_members_that_are_not_fmu_instances_step_and_read_through_their_own_calls():
    """A stand-in member (a test's or a tool's): its do_step and plain getters, errors as they raise."""
    class StandIn:
        def __init__(self):
            self.name, self.time, self.steps = "stand-in", None, []

        def do_step(self, t, h):
            self.steps.append((round(t, 9), h))

    fmu = StandIn()
    member = Member(fmu, 2)
    member.outputs.append((lambda: [len(fmu.steps), 0.5], 0, 2))
    values = [0, 0.0]
    step = step_plan("jacobi", [member], values, H)
    for k in range(4):
        step(k, k * H)
    assert fmu.steps == [(0.0, 2 * H), (0.2, 2 * H)] and values == [2, 0.5] and fmu.time == 0.2
    member.outputs[0] = (lambda: 1 / 0, 0, 2)
    with pytest.raises(ZeroDivisionError):
        step_plan("jacobi", [member], values, H)(0, 0.0)


# ------------------------------------------------------------------ the recorder
ODD_FLOATS = [0.1 + 0.2, 1.0, -0.0, 1e16, 1e-5, 0.0001, 5e-324, 1.7976931348623157e308, float("inf"),
              float("-inf"), float("nan"), 123456789.125, -2.5e-300, 0.12000000000000001]


def csv_text(columns: list[str], rows: list[tuple]) -> str:
    """What csv.writer (the recorder's format before issue 19) writes for the header and the rows."""
    out = io.StringIO(newline="")
    w = csv.writer(out)
    w.writerow(["time", *columns])
    w.writerows(rows)
    return out.getvalue()


def record(tmp_path, columns: list[str], rows: list[tuple], tick: float = 0.0) -> tuple[str, RunRecorder]:
    now = [0.0]
    rec = RunRecorder(tmp_path, columns, clock=lambda: now[0])
    for t, *values in rows:
        now[0] += tick
        rec.row(t, values)
    rec.close()
    return (tmp_path / TIMESERIES).read_bytes().decode(), rec


@pytest.mark.parametrize("tick", [0.0, FLUSH_S / 3], ids=["one block", "flushed in blocks"])
def test_recorded_numbers_are_the_text_the_csv_module_writes(tmp_path, tick):
    columns = ["a.x", "a.n", "a.b", "b.x[1,2]"]  # a name the csv module quotes
    rows = [(k * 0.01, ODD_FLOATS[k % len(ODD_FLOATS)], (-1) ** k * 2 ** (10 * k), k % 2 == 0, k / 7)
            for k in range(40)]
    text, rec = record(tmp_path, columns, rows, tick)
    assert text == csv_text(columns, rows)
    assert '"b.x[1,2]"' in text and "\r\n" in text and "nan" in text and "1e+16" in text
    assert rec.rows == 40


def test_rows_of_other_values_are_written_by_the_csv_module(tmp_path):
    rows = [(0.0, None, "a,b"), (0.01, 1.5, 'say "hi"')]
    text, _ = record(tmp_path, ["p", "q"], rows)
    assert text == csv_text(["p", "q"], rows)
    assert ',"a,b"\r\n' in text and ",," not in text.splitlines()[0]


def test_a_row_of_another_length_is_written_as_given(tmp_path):
    rows = [(0.0, 1.0), (0.01, 2.0, 3.0)]
    text, _ = record(tmp_path, ["p"], rows)
    assert text == csv_text(["p"], rows)


def test_kept_rows_count_and_reach_the_file_on_close(tmp_path):
    now = [0.0]
    rec = RunRecorder(tmp_path, ["a"], clock=lambda: now[0])
    for k in range(5):
        rec.row(k * 0.01, [float(k)])
    assert rec.rows == 5
    assert (tmp_path / TIMESERIES).read_text().count("\n") == 2  # the header and the first row
    rec.close()
    assert (tmp_path / TIMESERIES).read_text().count("\n") == 6


# ------------------------------------------------------------------ end to end, compiled FMU
def integrator_fmu(out_dir: Path) -> Path:
    """tests/third_party_fmu's FMI 2 Integrator.fmu, built here, or a skip with the reason it cannot be."""
    if sys.platform == "win32":
        pytest.skip("the C test FMUs are built with gcc for Linux/macOS only")
    spec = importlib.util.spec_from_file_location(
        "third_party_fmu_build", Path(__file__).resolve().parent / "third_party_fmu" / "build.py")
    build = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = build  # its dataclasses look their module up while it loads
    spec.loader.exec_module(build)
    if build.compiler() is None:
        pytest.skip("gcc not found: cannot compile the C test FMUs in tests/third_party_fmu/")
    return build.build_fmu(2, out_dir)


def test_an_instance_in_the_middle_ends_the_run_and_the_last_one_still_steps(tmp_path):
    from master.run.cosim import CoSimulation
    from master.scenario.loader import load_scenario

    fmu = integrator_fmu(tmp_path / "fmus")
    shutil.copy(fmu, tmp_path / fmu.name)
    blocks = [f'[fmus.{n}]\nfmu = "{fmu.name}"\n[fmus.{n}.parameters]\nk = 1.0\n'
              + ("stop_at = 0.5\n" if n == "b" else "") for n in ("a", "b", "c")]
    path = tmp_path / "three.toml"
    path.write_text("[time]\nstop = 1.0\nstep = 0.1\n\n" + "\n".join(blocks))
    result = CoSimulation(load_scenario(path), tmp_path / "run", quiet=True).run()
    assert result.status == "stopped", result.error
    meta = json.loads((tmp_path / "run" / "metadata.json").read_text())
    assert meta["stop_reason"] == "terminated by instance 'b' at t = 0.5 s" and meta["steps_done"] == 5
    with open(tmp_path / "run" / TIMESERIES, newline="") as f:
        last = list(csv.DictReader(f))[-1]
    assert float(last["time"]) == pytest.approx(0.5)
    assert [last[f"{n}.n_steps"] for n in "abc"] == ["5", "5", "5"]  # c stepped the step b ended with
