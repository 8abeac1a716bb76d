"""One table of a scenario file, read value by value: each value checked, each problem said as `key: reason`.

The scenario loader and every section reader (`[serial.NAME]`, `[world]`,
`[can]`, `[v2x]`, `[bridge]`, `[participants.NAME]`) check the same few kinds
of value: a number within a range, one of a few words, a name of an FMU
instance or of one of its variables, a key nobody reads. Reading them through
this one class keeps the checks and their wording the same everywhere.

Problems are collected, never raised: a getter that finds a bad value reports
it (with the table's dotted prefix, e.g. `can.status_rate_hz`) and returns the
default, so the reader goes on and finds the next problem too; a bad file is
then rejected with all of them listed. `ok` says afterwards whether anything
in the table (or a table read through `sub`) was reported, so the reader knows
whether what it built may be used.
"""
from __future__ import annotations

import difflib
import math
import re
import sys
from typing import Any, Callable, Iterable

from master.fmi.variables import family as type_family

Problem = Callable[[str, str], None]  # (dotted key, reason)


def deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """`over` laid on `base`: tables merge key by key, anything else replaces (scenario `extends`, `--set`)."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def did_you_mean(name: Any, candidates: Iterable[str]) -> str | None:
    """The hint "did you mean 'x' or 'y'?" for the names close to a misspelt one; None when none is close."""
    if not isinstance(name, str):
        return None
    close = difflib.get_close_matches(name, list(candidates), n=3)
    return "did you mean " + " or ".join(repr(c) for c in close) + "?" if close else None


def suggest(name: str, variables: dict) -> str:
    """What follows "unknown variable ...": the close names, or where to look them all up."""
    return did_you_mean(name, variables) or f"{len(variables)} variables; see `v2i info`"


def is_number(value: Any) -> bool:
    """A finite TOML integer or float. A bool is not a number here (TOML's true is no 1), nor NaN or inf,
    nor an integer too large for a float."""
    if isinstance(value, bool):
        return False
    if isinstance(value, int):
        return abs(value) <= sys.float_info.max
    return isinstance(value, float) and math.isfinite(value)


def _bounds(low, high, low_open: bool, high_open: bool) -> str:
    if high is None:
        return f"{'>' if low_open else '>='} {low:g}"
    if low is None:
        return f"{'<' if high_open else '<='} {high:g}"
    return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


class Table:
    """A TOML table under a dotted prefix, with a getter per kind of value.

    `Table(raw, "can", problem)` reads the `[can]` table; `problem(key, reason)`
    is the collector. A value that is not a table is reported as "expected
    {expected}" and read as an empty one. Keys are given relative to the prefix.
    """

    def __init__(self, raw: Any, prefix: str, problem: Problem | None = None, *, expected: str = "a table",
                 parent: Table | None = None):
        self.prefix = prefix
        self._parent = parent
        self._report = problem if problem is not None else parent._report
        self.reported = 0  # problems reported here or in a table read through sub()
        self.failed: set[str] = set()  # keys with a problem reported here (relative; "" for the table)
        self.raw: dict[str, Any] = raw if isinstance(raw, dict) else {}
        if not isinstance(raw, dict):
            self.problem(None, f"expected {expected}, got {type(raw).__name__}")

    # -- the table ------------------------------------------------------------------------
    @property
    def ok(self) -> bool:
        """No problem reported in this table (nor in one read through `sub`) so far."""
        return self.reported == 0

    def key(self, key: str | None) -> str:
        """The dotted key of `key` (None: of the table itself)."""
        if key is None:
            return self.prefix
        return f"{self.prefix}.{key}" if self.prefix else key

    def problem(self, key: str | None, reason: str) -> None:
        """Report `reason` for `key` of this table (None: the table itself)."""
        self._report(self.key(key), reason)
        self.failed.add(key or "")
        table: Table | None = self
        while table is not None:
            table.reported += 1
            table = table._parent

    def __contains__(self, key: str) -> bool:
        return key in self.raw

    def get(self, key: str, default: Any = None) -> Any:
        """The raw value, unchecked (for the odd values a reader checks itself)."""
        return self.raw.get(key, default)

    def sub(self, key: str, expected: str = "a table") -> Table:
        """The nested table `key` (empty when absent). A value that is no table is reported: its `ok` is False."""
        return Table(self.raw.get(key, {}), self.key(key), expected=expected, parent=self)

    def unknown_keys(self, allowed: Iterable[str], notes: dict[str, str] | None = None) -> None:
        """Report each key not in `allowed`, with the close ones; `notes` adds a word on particular keys."""
        allowed = tuple(allowed)
        for key in self.raw:
            if key in allowed:
                continue
            reason = f"unknown key (expected one of: {', '.join(allowed)})"
            hint = did_you_mean(key, allowed)
            if hint:
                reason += f"; {hint}"
            if notes and key in notes:
                reason += f"; {notes[key]}"
            self.problem(key, reason)

    # -- values ---------------------------------------------------------------------------
    def number(self, key: str, default: Any = None, *, low: float | None = None, high: float | None = None,
               low_open: bool = False, high_open: bool = False, integer: bool = False,
               expected: str | None = None, required: bool = False) -> Any:
        """A finite number (`integer`: a whole one, returned as int) within the bounds given.

        Reported as "expected {expected}, got ..." when `expected` words the
        value and its range, else as "expected a finite number > 0, got ..."
        (not a number) or "must be > 0, got ..." (out of range). An absent key
        gives `default` (reported when `required`). A whole float such as 2.0
        counts as an integer.
        """
        bounds = _bounds(low, high, low_open, high_open) if low is not None or high is not None else ""
        what = expected or ("an integer" if integer else "a finite number") + (f" {bounds}" if bounds else "")
        if key not in self.raw:
            if required:
                self.problem(key, f"required: {what}")
            return default if default is None else (int(default) if integer else float(default))
        value = self.raw[key]
        if not is_number(value) or (integer and value != int(value)):
            self.problem(key, f"expected {what}, got {value!r}")
            return default
        if ((low is not None and (value < low or (low_open and value == low)))
                or (high is not None and (value > high or (high_open and value == high)))):
            self.problem(key, f"expected {expected}, got {value!r}" if expected else f"must be {bounds}, got {value!r}")
            return default
        return int(value) if integer else float(value)

    def choice(self, key: str, choices: Iterable[str], default: str) -> str:
        """One of `choices` (the default when absent or bad)."""
        choices = tuple(choices)
        value = self.raw.get(key, default)
        if value not in choices:
            hint = did_you_mean(value, choices)
            self.problem(key, f"expected one of {', '.join(choices)}, got {value!r}" + (f"; {hint}" if hint else ""))
            return default
        return value

    def boolean(self, key: str, default: bool) -> bool:
        value = self.raw.get(key, default)
        if not isinstance(value, bool):
            self.problem(key, f"expected true or false, got {value!r}")
            return default
        return value

    def string(self, key: str, default: str | None = None, *, expected: str = "a non-empty string",
               pattern: re.Pattern | None = None, required: bool = False) -> str | None:
        """A non-empty string (matching `pattern` when given); `default` when absent (reported when `required`)."""
        if key not in self.raw:
            if required:
                self.problem(key, f"required: {expected}")
            return default
        value = self.raw[key]
        if not isinstance(value, str) or not value or (pattern is not None and not pattern.match(value)):
            self.problem(key, f"expected {expected}, got {value!r}")
            return default
        return value

    def strings(self, key: str, default: list[str] | None = None, *, expected: str, one: bool = False,
                nonempty: bool = False) -> list[str] | None:
        """A list of non-empty strings (`one`: a single string counts as a list of it; `nonempty`: not [])."""
        if key not in self.raw:
            return default
        value = self.raw[key]
        if one and isinstance(value, str):
            value = [value]
        if (not isinstance(value, list) or (nonempty and not value)
                or not all(isinstance(v, str) and v for v in value)):
            self.problem(key, f"expected {expected}, got {value!r}")
            return default
        return list(value)

    def endpoints(self, key: str) -> list[str]:
        """Bus endpoints: one endpoint string or a list of them ([] when absent)."""
        return self.strings(key, [], one=True,
                            expected="an endpoint string or a list of them (e.g. \"tcp/10.0.0.1:7447\")")

    # -- FMU instances and variables --------------------------------------------------------
    def instance(self, key: str, instances: dict[str, Any], what: str) -> Any:
        """The FMU instance named by `key` (required; `what` says what it is for), or None."""
        name = self.raw.get(key)
        if not isinstance(name, str) or not name:
            self.problem(key, f"required: {what}")
            return None
        if name not in instances:
            self.problem(key, f"unknown instance {name!r} (instances: {', '.join(instances) or 'none'})")
            return None
        return instances[name]

    def fmu_variable(self, key: str, instance: Any, *, causality: str, family: str, default: str | None = None,
                     required: bool = True) -> str | None:
        """The name of a variable of `instance` with this causality and type family, or None.

        An optional variable left at its default that the FMU does not have is
        None without a problem. Without an instance (it was bad) only the
        name itself is checked.
        """
        name = self.raw.get(key, default)
        of = f" of {instance.name}" if instance is not None else ""
        if not isinstance(name, str) or not name:
            self.problem(key, f"expected a variable name{of}, got {name!r}")
            return None
        if instance is None:
            return name
        variables = instance.variables
        var = variables.get(name)
        if var is None:
            if not required and key not in self.raw:
                return None  # an optional default the FMU does not have
            self.problem(key, f"unknown variable {instance.name}.{name} ({suggest(name, variables)})")
            return None
        if var.causality != causality or type_family(var.type) != family:
            article = "an" if var.causality[0] in "aeiou" else "a"
            self.problem(key, f"{instance.name}.{name} is {article} {var.causality} of type {var.type}; "
                              f"expected a {family} {causality}")
            return None
        return name
