"""The master algorithm: how the FMUs due at a communication point exchange values and step.

One flat value table holds every observed output (slots pre-bound by
master.cosim); a member's inputs are set from slots and its outputs read back
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
"""
from __future__ import annotations

from typing import Any, Callable, Iterable, Sequence

from master.hooks import Member

StepFn = Callable[[int, float, float, Sequence[Member], list], None]


def set_inputs(member: Member, values: list[Any]) -> None:
    for setter, slots in member.inputs:
        setter([values[s] for s in slots])


def read_outputs(members: Iterable[Member], values: list[Any]) -> None:
    for m in members:
        for getter, first, end in m.outputs:
            values[first:end] = getter()


def jacobi(k: int, t: float, h: float, members: Sequence[Member], values: list[Any]) -> None:
    due = [m for m in members if k % m.multiple == 0]
    for m in due:
        set_inputs(m, values)
    for m in due:
        m.fmu.do_step(t, m.multiple * h)
    read_outputs(due, values)


def gauss_seidel(k: int, t: float, h: float, members: Sequence[Member], values: list[Any]) -> None:
    for m in members:
        if k % m.multiple == 0:
            set_inputs(m, values)
            m.fmu.do_step(t, m.multiple * h)
            read_outputs((m,), values)


ALGORITHMS: dict[str, StepFn] = {"jacobi": jacobi, "gauss-seidel": gauss_seidel}


def algorithm(ordering: str) -> StepFn:
    """The step function of `[time] ordering` (validated by the scenario loader)."""
    try:
        return ALGORITHMS[ordering]
    except KeyError:
        raise ValueError(f"unknown ordering {ordering!r} (expected one of: {', '.join(ALGORITHMS)})") from None
