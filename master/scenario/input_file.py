"""Input files: FMU inputs driven from a CSV table, as `fmpy.simulate_fmu` takes input signals.

    [fmus.car]
    fmu = "car.fmu"
    input = "car_in.csv"          # or [fmus.car.input] file = "car_in.csv"

The file has a header row: `time`, then one column per driven input, named
after the input variable. Times are in seconds and strictly increasing; the
first row is at or before `[time] start`. At each communication point t the
master sets, before the instance steps:

* a continuous Real input (Real/Float64/Float32 with variability continuous):
  the value interpolated linearly between the rows around t;
* any other input (discrete Reals, integers, Booleans): the value of the last
  row at or before t (sample and hold).

After the last row the last values hold. Every cell is checked when the
scenario is loaded, against the variable's kind, its type range and its
declared min/max, so a bad file never half-runs.
"""
from __future__ import annotations

import bisect
import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from master.fmi.variables import check_scalar, describe_type, family, shape, unsupported_reason
from master.hooks import Hook
from master.scenario.tables import Table, did_you_mean

INPUT_KEYS = ("file",)
TIME_COLUMN = "time"
_MAX_CELL_PROBLEMS = 5  # per file; the rest are counted
_TRUE, _FALSE = ("1", "true"), ("0", "false")


def _tolerance(t: float) -> float:
    """How far a communication point may fall short of a row's time and still be at it
    (t0 + k*h is not exactly the decimal the file holds)."""
    return 1e-9 * max(1.0, abs(t))


@dataclass
class InputColumn:
    name: str  # the input variable
    values: list[Any]  # one per row, of the variable's Python type (float, int, bool)
    interpolate: bool  # continuous Real: linear between rows; else the last row at or before t


@dataclass
class InputTable:
    path: Path
    times: list[float]
    columns: list[InputColumn]

    def __post_init__(self):
        self._times = np.asarray(self.times, dtype=float)
        self._arrays = {c.name: np.asarray(c.values, dtype=float) for c in self.columns if c.interpolate}

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.columns]

    def values_at(self, t: float) -> dict[str, Any]:
        """Every column's value at t (interpolated or held; before the first row: the first row's)."""
        row = max(bisect.bisect_right(self.times, t + _tolerance(t)) - 1, 0)
        out: dict[str, Any] = {}
        for column in self.columns:
            if column.interpolate:
                out[column.name] = float(np.interp(t, self._times, self._arrays[column.name]))
            else:
                out[column.name] = column.values[row]
        return out


def read_input(spec: Table, variables: dict[str, Any], fmu_name: str, fmi3: bool, base_dir: Path,
               start: float) -> InputTable | None:
    """The input file of one `[fmus.NAME]` table (`input = "f.csv"` or `[fmus.NAME.input] file = ...`),
    or None when it has none or the file has problems (each reported on `spec`)."""
    if "input" not in spec:
        return None
    value = spec.get("input")
    if isinstance(value, dict):
        sub = spec.sub("input")
        sub.unknown_keys(INPUT_KEYS)
        file = sub.string("file", required=True, expected="the path of a CSV file (time + input columns)")
        report = lambda reason: sub.problem("file", reason)  # noqa: E731
    elif isinstance(value, str) and value:
        file = value
        report = lambda reason: spec.problem("input", reason)  # noqa: E731
    else:
        spec.problem("input", f"expected the path of a CSV file or a table with file = \"...\", got {value!r}")
        return None
    if file is None:
        return None
    path = Path(file).expanduser()
    path = path if path.is_absolute() else base_dir / path
    table, problems = load_input_table(path, variables, fmu_name, fmi3, start)
    for reason in problems:
        report(reason)
    return table if not problems else None


def load_input_table(path: Path, variables: dict[str, Any], fmu_name: str, fmi3: bool,
                     start: float) -> tuple[InputTable | None, list[str]]:
    """Read and check a CSV input file against the FMU's variables; (table, []) or (None, problems)."""
    try:
        with open(path, newline="") as f:
            reader = csv.reader(f)  # (line number, cells) of every row that is not blank
            numbered = [(reader.line_num, row) for row in reader if any(cell.strip() for cell in row)]
    except OSError as exc:
        return None, [f"cannot read {path}: {exc.strerror or exc}"]
    except (UnicodeDecodeError, csv.Error) as exc:
        return None, [f"{path.name} is not a readable CSV file: {exc}"]
    rows = [row for _, row in numbered]
    if not rows:
        return None, [f"{path.name} is empty: expected a header row \"time,<input>,...\" and rows of values"]
    header = [cell.strip() for cell in rows[0]]
    problems = []
    if header[0] != TIME_COLUMN:
        problems.append(f"{path.name}: the first column must be \"time\", got {header[0]!r}")
    inputs = sorted(n for n, v in variables.items() if v.causality == "input")
    columns: list[tuple[int, Any]] = []  # (column index, variable)
    seen: set[str] = set()
    for index, name in enumerate(header[1:], start=1):
        reason = _column_problem(name, variables, inputs, fmu_name)
        if name in seen:
            reason = f"column {name!r} appears twice"
        seen.add(name)
        if reason:
            problems.append(f"{path.name}: {reason}")
        else:
            columns.append((index, variables[name]))
    if len(header) < 2:
        problems.append(f"{path.name}: no input columns after \"time\" (inputs of {fmu_name}: "
                        f"{', '.join(inputs) or 'none'})")
    if len(rows) < 2:
        problems.append(f"{path.name} has a header but no rows of values")
    if problems:
        return None, problems

    cells: list[str] = []  # problems with single cells, reported up to _MAX_CELL_PROBLEMS
    times: list[float] = []
    values: dict[str, list[Any]] = {var.name: [] for _, var in columns}
    for line, row in numbered[1:]:
        if len(row) != len(header):
            cells.append(f"line {line}: expected {len(header)} cells, got {len(row)}")
            continue
        t = _number(row[0])
        if t is None:
            cells.append(f"line {line}: time {row[0].strip()!r} is not a finite number")
            continue
        if times and t <= times[-1]:
            cells.append(f"line {line}: time {t:g} is not after the previous row's {times[-1]:g} "
                         "(times must be increasing)")
            continue
        times.append(t)
        for index, var in columns:
            value, reason = _cell(row[index], var, fmi3)
            if reason:
                cells.append(f"line {line}, column {var.name!r}: {reason}")
            values[var.name].append(value)
    if times and times[0] > start + _tolerance(start):
        problems.append(f"{path.name} starts at t = {times[0]:g} s, after time.start = {start:g} s: "
                        "the first row must give the inputs' values at the start")
    if cells:
        more = len(cells) - _MAX_CELL_PROBLEMS
        problems += [f"{path.name} {c}" for c in cells[:_MAX_CELL_PROBLEMS]]
        if more > 0:
            problems.append(f"{path.name}: {more} more bad cell(s)")
    if problems:
        return None, problems
    table = InputTable(path, times, [InputColumn(var.name, values[var.name], _interpolated(var))
                                     for _, var in columns])
    return table, []


def _column_problem(name: str, variables: dict[str, Any], inputs: list[str], fmu_name: str) -> str | None:
    var = variables.get(name)
    if var is None:
        hint = did_you_mean(name, inputs) or f"inputs of {fmu_name}: {', '.join(inputs) or 'none'}"
        return f"unknown column {name!r}: no input of that name ({hint})"
    if var.causality != "input":
        return f"column {name!r}: {name} is {'an' if var.causality[0] in 'aeiou' else 'a'} {var.causality}, " \
               "only inputs can be driven from a file"
    reason = unsupported_reason(var)
    if reason:
        return f"column {name!r}: {reason}"
    if shape(var):
        return f"column {name!r}: {name} is a {describe_type(var)} array; input files drive scalar inputs only"
    if family(var.type) == "string":
        return f"column {name!r}: {name} is a String; input files drive numeric and Boolean inputs only"
    return None


def _interpolated(var) -> bool:
    """Continuous Reals are interpolated; everything else (discrete Reals included) is held."""
    return family(var.type) == "real" and var.variability == "continuous"


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _cell(text: str, var, fmi3: bool) -> tuple[Any, str | None]:
    """The value of one cell for `var` (float, int or bool) and why it is bad (None when good)."""
    text = text.strip()
    fam = family(var.type)
    if fam == "boolean":
        if text.lower() in _TRUE:
            return True, None
        if text.lower() in _FALSE:
            return False, None
        return None, f"expected a Boolean (0, 1, true or false), got {text!r}"
    number = _number(text)
    if number is None:
        return None, f"expected a finite number, got {text!r}"
    if fam == "integer":
        try:
            value = int(text)
        except ValueError:
            if number != int(number):
                return None, f"expected an integer for {var.type} {var.name}, got {text!r}"
            value = int(number)
    else:
        value = number
    return value, check_scalar(var, value, fmi3)


class InputFiles(Hook):
    """The scenario's input files as a manipulator: before each step an instance takes, its
    file-driven inputs are set to their values at that communication point.

    `bind` and `apply` are also called by the master's initialization (master.run.initialization),
    so that the start row is in place before connections are propagated and the t = start
    row is recorded.
    """

    name = "input_files"

    def __init__(self, scenario):
        self.tables: dict[str, InputTable] = {
            name: inst.input for name, inst in scenario.instances.items() if getattr(inst, "input", None)}
        self._drive: list[tuple[int, InputTable, list]] = []  # (step multiple, table, [(setter, names)])

    def __bool__(self) -> bool:
        return bool(self.tables)

    def bind(self, members) -> None:
        """Pre-bind one setter per getter/setter family of each instance's driven inputs."""
        self._drive = []
        for name, table in self.tables.items():
            member = members[name]
            fmu = member.fmu
            groups: dict[str, list[str]] = {}
            for column in table.names:
                groups.setdefault(fmu.access_key(column), []).append(column)
            setters = [(fmu.accessor(key, [fmu.variables[n].valueReference for n in names], setter=True), names)
                       for key, names in groups.items()]
            self._drive.append((member.multiple, table, setters))

    def apply(self, k: int, t: float) -> None:
        """Set the inputs of every instance due at base step k to their values at t."""
        for multiple, table, setters in self._drive:
            if k % multiple:
                continue
            now = table.values_at(t)
            for setter, names in setters:
                setter([now[n] for n in names])

    def open(self, ctx) -> dict:
        return {name: {"file": str(table.path), "rows": len(table.times),
                       "interpolated": [c.name for c in table.columns if c.interpolate],
                       "held": [c.name for c in table.columns if not c.interpolate]}
                for name, table in self.tables.items()}

    def before_step(self, k: int, t: float) -> None:
        self.apply(k, t)
