"""Conditions over a run's signals, written in the scenario: `"cav.v < 0.1 and t > 5"`, `"distance(cav, ev) < 20"`.

A condition is a small expression language, parsed with Python's `ast` and
compiled to closures (never `eval`): numbers; `t` (simulation time, s);
`instance.variable` (an FMU output or any recorded variable); arithmetic
`+ - * /`, unary `-`, `abs(x)`; comparisons `< <= > >= == !=` (chains too);
`and`, `or`, `not`; `distance(a, b)`: metres between the (x, y) outputs of two
instances (for vehicles: their rear axles). Anything else is refused when the
scenario is loaded, naming the expression and what is wrong, with a "did you
mean" for an unknown variable. Scenario stop conditions (`[time] stop_on`)
use it; so will scenario events.
"""
from __future__ import annotations

import ast
import difflib
import math
import operator
from dataclasses import dataclass, field
from typing import Callable, Iterable

from master.hooks import Hook

_COMPARE = {ast.Lt: operator.lt, ast.LtE: operator.le, ast.Gt: operator.gt, ast.GtE: operator.ge,
            ast.Eq: operator.eq, ast.NotEq: operator.ne}
_ARITH = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul, ast.Div: operator.truediv}

Values = Callable[[str], float]  # signal name ("cav.v") -> its current value


class ConditionError(ValueError):
    """A condition that cannot be compiled; the message says what and where."""


@dataclass
class Condition:
    """A compiled condition: `holds(t, value)` where value(name) gives a signal's current value."""

    text: str
    signals: list[str] = field(default_factory=list)  # every "instance.variable" it reads
    _fn: Callable[[float, Values], object] | None = None

    def holds(self, t: float, value: Values) -> bool:
        try:
            return bool(self._fn(t, value))
        except ZeroDivisionError:
            return False


def compile_condition(text: str, signals: Iterable[str], positions: Iterable[str] = ()) -> Condition:
    """Compile `text` against the known `signals` ("inst.var") and the instances with x, y outputs
    (`positions`, for distance()); ConditionError says what is wrong."""
    known = set(signals)
    placed = set(positions)
    if not isinstance(text, str) or not text.strip():
        raise ConditionError(f"expected an expression such as \"cav.v < 0.1\", got {text!r}")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ConditionError(f"{text!r} is not an expression: {exc.msg}") from None
    cond = Condition(text)

    def signal(name: str) -> Callable:
        if name not in known:
            close = difflib.get_close_matches(name, sorted(known), n=3)
            hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            raise ConditionError(f"{text!r}: unknown signal {name!r}{hint}")
        if name not in cond.signals:
            cond.signals.append(name)
        return lambda t, v: v(name)

    def instance(node) -> str:
        if not isinstance(node, ast.Name):
            raise ConditionError(f"{text!r}: distance() takes two instance names, e.g. distance(cav, ev)")
        if node.id not in placed:
            close = difflib.get_close_matches(node.id, sorted(placed), n=3)
            hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            raise ConditionError(f"{text!r}: distance() needs an instance with x and y outputs, "
                                 f"not {node.id!r}{hint}")
        signal(f"{node.id}.x")
        signal(f"{node.id}.y")
        return node.id

    def build(node) -> Callable:
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
            value = float(node.value)
            return lambda t, v: value
        if isinstance(node, ast.Name):
            if node.id == "t":
                return lambda t, v: t
            raise ConditionError(f"{text!r}: unknown name {node.id!r} (signals are written instance.variable; "
                                 "t is the simulation time)")
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            return signal(f"{node.value.id}.{node.attr}")
        if isinstance(node, ast.BoolOp):
            parts = [build(p) for p in node.values]
            if isinstance(node.op, ast.And):
                return lambda t, v: all(p(t, v) for p in parts)
            return lambda t, v: any(p(t, v) for p in parts)
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.Not, ast.USub)):
            inner = build(node.operand)
            if isinstance(node.op, ast.Not):
                return lambda t, v: not inner(t, v)
            return lambda t, v: -inner(t, v)
        if isinstance(node, ast.BinOp) and type(node.op) in _ARITH:
            op, left, right = _ARITH[type(node.op)], build(node.left), build(node.right)
            return lambda t, v: op(left(t, v), right(t, v))
        if isinstance(node, ast.Compare) and all(type(o) in _COMPARE for o in node.ops):
            terms = [build(node.left)] + [build(c) for c in node.comparators]
            ops = [_COMPARE[type(o)] for o in node.ops]

            def compare(t, v):
                values = [f(t, v) for f in terms]
                return all(op(a, b) for op, a, b in zip(ops, values, values[1:]))
            return compare
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
            if node.func.id == "abs" and len(node.args) == 1:
                inner = build(node.args[0])
                return lambda t, v: abs(inner(t, v))
            if node.func.id == "distance" and len(node.args) == 2:
                a, b = (instance(arg) for arg in node.args)
                ax, ay, bx, by = f"{a}.x", f"{a}.y", f"{b}.x", f"{b}.y"
                return lambda t, v: math.hypot(v(ax) - v(bx), v(ay) - v(by))
            raise ConditionError(f"{text!r}: unknown function {ast.unparse(node.func)}() "
                                 "(known: abs(x), distance(a, b))")
        raise ConditionError(f"{text!r}: {ast.unparse(node)!r} is not allowed here (numbers, t, instance.variable, "
                             "+ - * /, comparisons, and/or/not, abs(), distance())")

    cond._fn = build(tree.body)
    return cond


COLLISION = "collision"  # the stop_on word for the collision check's first contact (master.run.collision)


def signals_of(instances) -> tuple[list[str], list[str]]:
    """(every readable "inst.var" of the scenario's instances, the instances with x and y outputs)."""
    signals, positions = [], []
    for name, inst in instances.items():
        outputs = set()
        for var in inst.model_description.modelVariables:
            if (var.type in ("Real", "Float64", "Float32", "Integer", "Int32", "Boolean") and "[" not in var.name
                    and not var.dimensions):  # an FMI 3 array is no one number
                signals.append(f"{name}.{var.name}")
                if var.causality == "output":
                    outputs.add(var.name)
        if {"x", "y"} <= outputs:
            positions.append(name)
    return signals, positions


class StopConditions(Hook):
    """`[time] stop_on` conditions over signals as an observer of the loop: the first that holds after a
    step ends the run there (the collision word is the collision check's, not this hook's)."""

    name = "stop_on"

    def __init__(self, conditions: list[Condition]):
        self.conditions = conditions
        self._getters: dict[str, Callable[[], float]] = {}
        self._ctx = None
        self.fired: dict[str, float] | None = None

    @classmethod
    def for_scenario(cls, scenario) -> "StopConditions | None":
        texts = [c for c in scenario.time.stop_on if c != COLLISION]
        if not texts:
            return None
        signals, positions = signals_of(scenario.instances)
        return cls([compile_condition(text, signals, positions) for text in texts])

    def open(self, ctx) -> dict:
        self._ctx = ctx
        for cond in self.conditions:
            for sig in cond.signals:
                if sig not in self._getters:
                    inst, var = sig.split(".", 1)
                    fmu = ctx.members[inst].fmu
                    get = fmu.accessor(fmu.access_key(var), [fmu.variables[var].valueReference], setter=False)
                    self._getters[sig] = lambda get=get: float(get()[0])
        return {"conditions": [c.text for c in self.conditions]}

    def after_step(self, k: int, t_next: float) -> None:
        if self.fired is not None:
            return
        value = lambda name: self._getters[name]()  # noqa: E731
        for cond in self.conditions:
            if cond.holds(t_next, value):
                self.fired = {"condition": cond.text, "t": t_next}
                self._ctx.request_stop(f"stop_on {cond.text!r} held at t = {t_next:.2f} s")
                return

    def close(self, outcome=None) -> dict:
        return {"conditions": [c.text for c in self.conditions], "fired": self.fired}
