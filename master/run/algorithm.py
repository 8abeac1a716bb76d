"""The master algorithm: how the FMUs due at a communication point exchange values and step.

One flat value table holds every observed output (slots pre-bound by
master.run.cosim); a member's inputs are set from slots and its outputs read back
into them. The two orderings differ only in when an instance's outputs become
visible to the others:

* `jacobi` (default): every due instance reads the outputs of the previous
  communication point, then all step, then all outputs are read. Each
  connection carries one step (of its source) of delay.
* `gauss-seidel`: instances step one after another in file order; an instance
  reads what its predecessors produced in this same step (no delay on forward
  connections, one source step on backward ones).

Instances with `step_multiple = m` are due every m base steps and step m*h;
between their steps their outputs hold.

The loop runs a `step_plan`: the transfers of the members due at a step,
flattened once per pattern of due members (every step when all step at the base
rate) instead of being looked up per member and step, the FMUs' own doStep and
getters called without a wrapper frame each, and their errors turned into the
same SimulationError (instance, call) by one handler around all the steps and
one around all the reads. At N = 10 compiled FMUs these per-call costs were a
good part of the master's overhead over a bare fmpy loop (benchmarks/master_overhead.py).
"""
from __future__ import annotations

from math import lcm
from operator import call
from typing import Any, Callable, Iterable, Sequence

from master.errors import SimulationError
from master.hooks import Member

StepFn = Callable[[int, float], None]  # step(k, t): the base step k, from t to t + h


def set_inputs(member: Member, values: list[Any]) -> None:
    for setter, slots in member.inputs:
        setter([values[s] for s in slots])


def read_outputs(members: Iterable[Member], values: list[Any]) -> None:
    for m in members:
        for getter, first, end in m.outputs:
            values[first:end] = getter()


class Transfers:
    """What a group of members does in a step, flattened: their input setters, their doSteps, their reads.

    `whole_table`: the group's outputs fill the value table from slot 0 on, in order (every member
    due, as master.run.cosim binds the slots): the reads then build the table in one piece.
    """

    def __init__(self, members: Sequence[Member], values: list[Any], h: float):
        self.values = values
        self.inputs = [(setter, slots) for m in members for setter, slots in m.inputs]
        # (fmu, do(t, h), its step size): FmuInstance.stepper, or for anything else that quacks like one, do_step
        self.steps = [(m.fmu, _stepper(m.fmu), m.multiple * h) for m in members]
        # (read, arg, first, end, fmu): read(arg) is the getter's call without its checks where it has one
        # (FmuInstance.accessor's read_call: fmpy's getter and the value references), else getter()
        self.outputs = [(*getattr(getter, "read_call", (call, getter)), first, end, m.fmu)
                        for m in members for getter, first, end in m.outputs]
        ends = [0] + [end for *_, end, _ in self.outputs]
        self.whole_table = (ends[-1] == len(values)
                            and all(first == end for (_, _, first, _, _), end in zip(self.outputs, ends)))
        self.reads = [(read, arg, fmu) for read, arg, _, _, fmu in self.outputs]
        self.read_outputs = self._read_table if self.whole_table else self._read_slots

    def set_inputs(self) -> None:
        values = self.values
        for setter, slots in self.inputs:
            setter([values[s] for s in slots])

    def _read_slots(self) -> None:
        values = self.values
        try:
            for read, arg, first, end, fmu in self.outputs:
                values[first:end] = read(arg)
        except SimulationError:
            raise
        except Exception as exc:
            _read_failed(fmu, exc)  # the instance whose read raised (the loop variable keeps it)

    def _read_table(self) -> None:
        table: list[Any] = []
        extend = table.extend
        try:
            for read, arg, fmu in self.reads:
                extend(read(arg))
        except SimulationError:
            raise
        except Exception as exc:
            _read_failed(fmu, exc)
        self.values[:] = table  # in place: the hooks hold this list


def _read_failed(fmu, exc: Exception) -> None:
    """A SimulationError naming the instance and "get values", as FmuInstance's checked getter raises it."""
    fail = getattr(fmu, "fail", None)
    if fail is None:  # not an FmuInstance: its getters raise what they raise
        raise exc
    fail("get values", exc)


def _stepper(fmu) -> Callable[[float, float], None]:
    stepper = getattr(fmu, "stepper", None)
    return stepper() if stepper is not None else fmu.do_step


def do_steps(steps: Sequence[tuple], t: float) -> None:
    """doStep of every (fmu, do, h) from t, setting each FMU's `time` first as FmuInstance.do_step does.

    A raising doStep goes to its FMU's `step_failed` (a SimulationError naming it and doStep); an FMU
    that ended the simulation with this step returns from there, and the FMUs after it still step.
    """
    try:
        for fmu, do, h in steps:
            fmu.time = t
            do(t, h)
    except SimulationError:
        raise
    except Exception as exc:
        step_failed = getattr(fmu, "step_failed", None)
        if step_failed is None:  # not an FmuInstance: its do_step handles its own errors
            raise
        step_failed(exc, t, h)
        after = next(i for i, entry in enumerate(steps) if entry[0] is fmu) + 1
        do_steps(steps[after:], t)


def step_plan(ordering: str, members: Sequence[Member], values: list[Any], h: float) -> StepFn:
    """step(k, t) of `[time] ordering` over `members` (in file order), from t to t + h, reading into and
    setting from `values`. Members and their transfers must not change after this: the plan is built once."""
    build = _ORDERINGS.get(ordering)
    if build is None:
        raise ValueError(f"unknown ordering {ordering!r} (expected one of: {', '.join(_ORDERINGS)})")
    members = list(members)
    period = lcm(*(m.multiple for m in members)) if members else 1
    if period == 1:  # everyone steps every base step: one plan
        return build(members, values, h)
    plans: dict[int, StepFn] = {}  # k % period -> the plan of the members due then, built on first use

    def step(k: int, t: float) -> None:
        phase = k % period
        plan = plans.get(phase)
        if plan is None:
            plan = plans[phase] = build([m for m in members if phase % m.multiple == 0], values, h)
        plan(k, t)
    return step


def _jacobi(due: Sequence[Member], values: list[Any], h: float) -> StepFn:
    transfers = Transfers(due, values, h)
    steps, set_inputs, read_outputs = transfers.steps, transfers.set_inputs, transfers.read_outputs
    if not transfers.inputs:  # nothing connected into these members: nothing to set
        def step(k: int, t: float) -> None:
            do_steps(steps, t)
            read_outputs()
        return step

    def step_connected(k: int, t: float) -> None:
        set_inputs()
        do_steps(steps, t)
        read_outputs()
    return step_connected


def _gauss_seidel(due: Sequence[Member], values: list[Any], h: float) -> StepFn:
    each = [Transfers((m,), values, h) for m in due]

    def step(k: int, t: float) -> None:
        for transfers in each:
            transfers.set_inputs()
            do_steps(transfers.steps, t)
            transfers.read_outputs()
    return step


_ORDERINGS: dict[str, Callable[[Sequence[Member], list, float], StepFn]] = {
    "jacobi": _jacobi, "gauss-seidel": _gauss_seidel}
