"""Consistent start values: connections propagated while the FMUs are in initialization mode.

Without this the t = start row shows a connected input at its start value
while its source already holds another value, and the first step runs on it.
FMI's initialization mode allows setting inputs and reading outputs, so the
master iterates before leaving it: set every connected input from its
source's output, read the outputs back, until nothing changes. A chain
A.out -> B.in -> B.out -> C.in settles in one sweep per link; the number of
sweeps is bounded by the number of connections (plus one to see that nothing
changed), which is enough for any chain.

Outputs that depend directly on inputs (the FMUs' ModelStructure
`dependencies`; none given means "on every input", as FMI says) connected in
a cycle form an algebraic loop. If the values do not settle within the bound
the run fails with the cycle named, instance by instance and variable by
variable; a loop that settles (its values already agree) is accepted.
"""
from __future__ import annotations

import graphlib
from typing import Any, Sequence

from master.run.algorithm import read_outputs, set_inputs
from master.errors import SimulationError
from master.hooks import Member


def initialize(members: dict[str, Member], values: list[Any], scenario, inputs=None) -> dict[str, Any]:
    """Before exitInitializationMode: input files at t = start, then connections to a fixed point.

    Returns the metadata section: how many sweeps the connections took to settle.
    """
    t0 = scenario.time.start
    if inputs:
        inputs.bind(members)
        inputs.apply(0, t0)
    sweeps = settle(list(members.values()), values, limit=len(scenario.connections) + 2,
                    loop=lambda: feedthrough_loop(scenario.instances, scenario.connections), t0=t0)
    return {"connection_sweeps": sweeps}


def settle(members: Sequence[Member], values: list[Any], limit: int, loop=lambda: None, t0: float = 0.0) -> int:
    """Set inputs from outputs and read the outputs again until they no longer change.

    Returns the sweeps that took (0 when nothing is connected). Raises a
    SimulationError when they still change after `limit` sweeps, naming the
    algebraic loop `loop()` finds (or, without one, the instances whose outputs changed).
    """
    if not any(m.inputs for m in members):
        return 0
    read_outputs(members, values)
    for sweep in range(1, limit + 1):
        for m in members:
            set_inputs(m, values)
        before = list(values)
        read_outputs(members, values)
        if _same(before, values):
            return sweep
    cycle = loop()
    if cycle:
        instance = cycle[0].split(".", 1)[0]
        raise SimulationError(instance, t0, "initialization",
                              f"algebraic loop {' -> '.join(cycle)}: these outputs depend directly on their "
                              f"instance's inputs and are connected in a cycle, and the connected values did "
                              f"not settle in {limit} sweeps; break the loop (e.g. with an instance whose "
                              "output does not depend directly on its input)")
    changed = [i for i, (a, b) in enumerate(zip(before, values)) if not _equal(a, b)]
    names = [_owner(members, i) for i in changed]
    instance = names[0] if names else "?"
    raise SimulationError(instance, t0, "initialization",
                          f"connected values did not settle in {limit} sweeps: outputs of "
                          f"{', '.join(dict.fromkeys(names))} still changed")


def feedthrough_loop(instances: dict[str, Any], connections) -> list[str] | None:
    """A cycle of "instance.variable" names through connections and direct feedthrough
    (first name repeated at the end), or None when there is none."""
    predecessors: dict[str, set[str]] = {}
    for conn in connections:
        predecessors.setdefault(f"{conn.dst}.{conn.dst_var}", set()).add(f"{conn.src}.{conn.src_var}")
    for name, inst in instances.items():
        md = inst.model_description
        inputs = [v.name for v in md.modelVariables if v.causality == "input"]
        for unknown in md.outputs:
            deps = unknown.dependencies
            feeding = inputs if deps is None else [v.name for v in deps if v.causality == "input"]
            if feeding:
                predecessors.setdefault(f"{name}.{unknown.variable.name}", set()).update(
                    f"{name}.{i}" for i in feeding)
    try:
        graphlib.TopologicalSorter(predecessors).prepare()
    except graphlib.CycleError as exc:
        cycle = list(exc.args[1][:-1])  # each node feeds the next; the first is repeated at the end
        order = list(instances)
        first = min(range(len(cycle)), key=lambda i: (order.index(cycle[i].split(".", 1)[0]), cycle[i]))
        cycle = cycle[first:] + cycle[:first]
        return cycle + cycle[:1]
    return None


def _equal(a, b) -> bool:
    return a == b or (a != a and b != b)  # NaN settles too


def _same(before: list, after: list) -> bool:
    return before == after or all(_equal(a, b) for a, b in zip(before, after))


def _owner(members: Sequence[Member], slot: int) -> str:
    for m in members:
        if any(first <= slot < end for _, first, end in m.outputs):
            return m.fmu.name
    return "?"
