"""master.scenario.conditions: the scenario's condition language compiles what it should and refuses the rest."""
from __future__ import annotations

import math

import pytest

from master.scenario.conditions import ConditionError, compile_condition

SIGNALS = ["cav.x", "cav.y", "cav.v", "ev.x", "ev.y", "ev.v", "tlc.state_2"]
VALUES = {"cav.x": 1.75, "cav.y": -10.0, "cav.v": 0.05, "ev.x": -20.0, "ev.y": -1.75, "ev.v": 16.7,
          "tlc.state_2": 3.0}


def holds(text: str, t: float = 6.0, values=VALUES) -> bool:
    return compile_condition(text, SIGNALS, positions=["cav", "ev"]).holds(t, values.__getitem__)


@pytest.mark.parametrize("text,expected", [
    ("cav.v < 0.1", True),
    ("cav.v < 0.1 and t > 7", False),
    ("cav.v < 0.1 and t > 5", True),
    ("not (ev.v > 10)", False),
    ("cav.v > 1 or tlc.state_2 == 3", True),
    ("0 < cav.v <= 0.05", True),
    ("abs(cav.y) > 9.5", True),
    ("-cav.y * 2 == 20", True),
    ("ev.v / 0 > 1", False),  # a division by zero does not hold (and does not crash the run)
])
def test_expressions(text, expected):
    assert holds(text) is expected


def test_distance_between_instances_and_signals_read():
    c = compile_condition("distance(cav, ev) < 25", SIGNALS, positions=["cav", "ev"])
    d = math.hypot(1.75 + 20.0, -10.0 + 1.75)
    assert c.holds(0.0, VALUES.__getitem__) is (d < 25)
    assert sorted(c.signals) == ["cav.x", "cav.y", "ev.x", "ev.y"]


@pytest.mark.parametrize("text,words", [
    ("cav.vv < 1", "unknown signal 'cav.vv'; did you mean 'cav.v'"),
    ("speed < 1", "unknown name 'speed'"),
    ("cav.v <", "is not an expression"),
    ("__import__('os').system('x')", "is not allowed here"),
    ("open('f') == 1", "unknown function open()"),
    ("cav.v if t else 1", "is not allowed here"),
    ("distance(cav, tlc) < 3", "needs an instance with x and y outputs, not 'tlc'"),
    ("'text' == cav.v", "is not allowed here"),
    ("", "expected an expression"),
])
def test_bad_conditions_say_what_is_wrong(text, words):
    with pytest.raises(ConditionError) as err:
        compile_condition(text, SIGNALS, positions=["cav", "ev"])
    assert words in str(err.value)
