"""Sweep files: a base scenario, the axes to vary, and the points they make.

    [sweep]
    name = "radio_loss"                # default: the file's name; the sweep folder's default name
    base = "../ima_case_study.toml"    # relative to this file
    combine = "product"                # how the axes combine: "product" (every combination) or "zip"
                                       # (the i-th value of every axis together; equal lengths)
    timeout_s = 900.0                  # wall seconds one point may take before it counts as failed
    report = false                     # write each point's report.html (`v2i report` can do it later)
    cpus_per_point = 1                 # what the Ray engine reserves per point

    [sweep.set]                        # laid over every point (like `v2i run --set`)
    "record.camera" = false

    [[sweep.axis]]
    name = "loss"                      # the table's column (default: the key's last part)
    key = "v2x.channel.loss_prob"      # a dotted key as `--set` takes it, and one of:
    values = [0.0, 0.1, 0.2]           #   a list of values
    # range = { start = 0.0, stop = 0.5, step = 0.1 }        #   stop included when a step lands on it
    # random = { dist = "uniform", low = 0.0, high = 0.5, n = 20, seed = 1 }
    #   dist: uniform | loguniform (low, high) | integers (low..high inclusive) | normal (mean, std)
    group = "radio"                    # optional: axes of one group zip together inside a product

    [[sweep.axis]]
    name = "radio"                     # no key: each value is a table of overrides, a variant ({}: none)
    values = [{ "v2x.channel.technology" = "dsrc" },
              { "v2x.channel.technology" = "cv2x", "v2x.channel.cbr_target" = 0.6 }]
    labels = ["dsrc", "cv2x-loaded"]   # how the table and the plots name each value

    [sweep.axes]                       # shorthand: KEY = [values] or { range = ... } or { random = ... }
    "fmus.ev.parameters.v0" = [11.2, 15.6]

    [sweep.plots]
    outcome_map = { x = "loss", y = "radio" }   # collision / avoided over two axes, min gap as colour
    curves = { x = "loss", by = "radio" }       # min gap and E2E p99 against one axis, a line per `by`

Every point has a stable id: a hash of everything it overrides (the `[sweep.set]`
values and its own), so a re-run recognises the points it has already run
whatever the order of the values, and a point whose settings changed is a new
point. Its folder is named from its parameters and the id, readable and unique.
The file is checked like a scenario: every problem with its key, at once.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from master.errors import ScenarioError
from master.scenario.overrides import Override, override, parse_key, toml_literal
from master.scenario.tables import Table, did_you_mean, is_number

COMBINE = ("product", "zip")
SWEEP_KEYS = ("name", "base", "combine", "timeout_s", "report", "cpus_per_point", "set", "axis", "axes", "plots",
              "dse", "summary")
AXIS_KEYS = ("name", "key", "values", "range", "random", "labels", "group")
PLOT_KEYS = ("outcome_map", "curves")
DISTRIBUTIONS = ("uniform", "loguniform", "integers", "normal")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
# columns of the table that are not axes (master.sweep.table) and the top-level names of metrics.json
RESERVED = ("point", "folder", "status", "error", "run_status", "wall_s", "host", "cpu", "collision",
            "first_collision_s", "min_gap_m", "min_ttc_s", "pet_s", "latency_ms", "pdr", "ipg_ms", "aoi_ms",
            "time_mode", "latency_policy", "stop_reason", "rtf", "clock_bound_ms")


class SweepError(ScenarioError):
    """A sweep file is invalid; `problems` holds one line per fault (`key: reason`)."""

    def __str__(self) -> str:
        lines = "\n".join(f"  {self.path}: {p}" for p in self.problems)
        return f"invalid sweep {self.path} ({len(self.problems)} problem(s)):\n{lines}"


@dataclass(frozen=True)
class Axis:
    """One dimension of the sweep: a key and its values, or a list of variants (tables of overrides)."""

    name: str
    key: str | None  # None: each value is a {dotted key: value} table
    values: tuple[Any, ...]
    labels: tuple[str, ...]
    group: str | None = None

    def overrides(self, i: int) -> list[tuple[str, Any]]:
        value = self.values[i]
        if self.key is not None:
            return [(self.key, value)]
        return list(value.items())

    def column(self, i: int) -> Any:
        """What the table holds for value i: the value itself when it is a plain number, string or bool,
        else its label."""
        value = self.values[i]
        if self.key is not None and (is_number(value) or isinstance(value, (str, bool))):
            return value
        return self.labels[i]


@dataclass(frozen=True)
class Point:
    """One run of the sweep."""

    index: int  # position in the sweep's order (for display only: the id is what identifies it)
    params: dict[str, Any]  # axis name -> table value
    labels: dict[str, str]  # axis name -> label
    overrides: tuple[Override, ...]  # [sweep.set] then the axes', in axis order
    id: str  # hash of the overrides
    folder: str  # readable name + id

    def describe(self) -> str:
        return ", ".join(f"{k}={v}" for k, v in self.labels.items()) or "(base)"


@dataclass
class Plots:
    outcome_map: tuple[str, str] | None = None  # (x axis, y axis)
    curves: tuple[str, str | None] | None = None  # (x axis, series axis)


@dataclass
class SweepSpec:
    path: Path
    name: str
    base: Path
    combine: str
    timeout_s: float
    report: bool
    cpus_per_point: float
    constants: tuple[Override, ...]
    axes: list[Axis]
    plots: Plots
    dse: dict[str, Any] = field(default_factory=dict)  # [sweep.dse]: master.sweep.dse reads it
    summary: dict[str, Any] = field(default_factory=dict)  # [sweep.summary]: safe_limit = AXIS
    raw: dict[str, Any] = field(default_factory=dict)

    def points(self) -> list[Point]:
        return make_points(self.axes, self.combine, self.constants)

    def axis(self, name: str) -> Axis:
        return next(a for a in self.axes if a.name == name)


# -- reading ------------------------------------------------------------------------------------------
def load_sweep(path: str | Path) -> SweepSpec:
    """Parse and check a sweep file (and that its base scenario loads with every point's overrides is
    left to the points: a bad point fails alone). SweepError lists every problem."""
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise SweepError(path, [f"cannot read file: {exc.strerror or exc}"]) from None
    except tomllib.TOMLDecodeError as exc:
        raise SweepError(path, [f"not valid TOML: {exc}"]) from None
    problems: list[str] = []

    def problem(key: str, reason: str) -> None:
        problems.append(f"{key}: {reason}")

    top = Table(raw, "", problem)
    top.unknown_keys(("sweep",))
    t = top.sub("sweep")
    if "sweep" not in raw:
        t.problem(None, "required: a [sweep] table with base = \"SCENARIO.toml\" and its axes")
    t.unknown_keys(SWEEP_KEYS)
    name = t.string("name", path.stem, pattern=re.compile(r"^[A-Za-z0-9_.\-]+$"),
                    expected="a name of letters, digits, _ . - (the sweep folder's default name)")
    base_text = t.string("base", None, required=True, expected="the path of the base scenario file")
    base = (path.parent / base_text).resolve() if base_text else path
    if base_text and not base.is_file():
        t.problem("base", f"no such scenario file: {base}")
    combine = t.choice("combine", COMBINE, "product")
    timeout_s = t.number("timeout_s", 1800.0, low=0, low_open=True, expected="wall seconds > 0")
    report = t.boolean("report", False)
    cpus = t.number("cpus_per_point", 1.0, low=0, low_open=True, expected="a number of CPUs > 0")
    constants = _constants(t.sub("set", "a table of KEY = value overrides"))
    axes = _axes(t)
    if combine == "zip" and axes:
        lengths = {a.name: len(a.values) for a in axes}
        if len(set(lengths.values())) > 1:
            t.problem("combine", f"\"zip\" needs axes of one length, got {lengths}")
    _check_groups(t, axes)
    plots = _plots(t.sub("plots"), axes)
    dse = t.get("dse", {})
    if not isinstance(dse, dict):
        t.problem("dse", f"expected a table, got {type(dse).__name__}")
        dse = {}
    summary = t.sub("summary")
    summary.unknown_keys(("safe_limit",))
    limit = summary.get("safe_limit")
    if limit is not None and limit not in [a.name for a in axes]:
        summary.problem("safe_limit", f"no axis named {limit!r} (axes: {', '.join(a.name for a in axes)})"
                        + _hint(limit, [a.name for a in axes]))
    if problems:
        raise SweepError(path, problems)
    return SweepSpec(path, name, base, combine, timeout_s, report, cpus, constants, axes, plots, dict(dse),
                     dict(summary.raw), raw)


def _hint(name: Any, names: list[str]) -> str:
    hint = did_you_mean(name, names)
    return f"; {hint}" if hint else ""


def _override(t: Table, where: str, key: Any, value: Any) -> Override | None:
    if not isinstance(key, str):
        t.problem(where, f"expected a dotted key string, got {key!r}")
        return None
    try:
        return override(key, value)
    except (ValueError, TypeError) as exc:
        t.problem(where, str(exc))
        return None


def _constants(t: Table) -> tuple[Override, ...]:
    out = []
    for key, value in t.raw.items():
        item = _override(t, key, key, value)
        if item is not None:
            out.append(item)
    return tuple(out)


def _axes(t: Table) -> list[Axis]:
    axes: list[Axis] = []
    items = t.get("axis", [])
    if not isinstance(items, list):
        t.problem("axis", f"expected an array of tables ([[sweep.axis]]), got {type(items).__name__}")
        items = []
    for i, item in enumerate(items):
        a = Table(item, f"sweep.axis[{i}]", parent=t)
        if a.ok:
            axis = _axis(a)
            if axis is not None:
                axes.append(axis)
    short = t.sub("axes", "a table of KEY = [values] (or { range = ... } / { random = ... })")
    for key, value in short.raw.items():
        spec = value if isinstance(value, dict) else {"values": value}
        axis = _axis(Table({"key": key, **spec}, short.key(key), parent=short))
        if axis is not None:
            axes.append(axis)
    if not axes and t.ok:
        t.problem(None, "no axes: add [[sweep.axis]] tables or a [sweep.axes] table")
    names = [a.name for a in axes]
    for name in sorted({n for n in names if names.count(n) > 1}):
        t.problem("axis", f"two axes are named {name!r}: give one a `name`")
    return axes


def _axis(a: Table) -> Axis | None:
    """One axis from its table ([[sweep.axis]], or a [sweep.axes] entry with its key put in)."""
    raw, problem = a.raw, a.problem
    a.unknown_keys(AXIS_KEYS)
    key = raw.get("key")
    if key is not None:
        if not isinstance(key, str):
            problem("key", f"expected a dotted key such as \"fmus.ev.parameters.v0\", got {key!r}")
            return None
        try:
            parse_key(key)
        except ValueError as exc:
            problem("key", str(exc))
            return None
    given = [k for k in ("values", "range", "random") if k in raw]
    if len(given) != 1:
        problem(None, "give exactly one of values = [...], range = { start, stop, step } or "
                      f"random = {{ dist, low, high, n, seed }} (got {', '.join(given) or 'none'})")
        return None
    kind = given[0]
    try:
        values = {"values": _values, "range": _range, "random": _random}[kind](raw[kind])
    except ValueError as exc:
        problem(kind, str(exc))
        return None
    if key is None:
        if kind != "values" or not all(isinstance(v, dict) for v in values):
            problem("values", "without `key`, each value is a table of overrides "
                              "({ \"fmus.ev.parameters.v0\" = 11.2, ... }; {} is the base as it is)")
            return None
        for i, variant in enumerate(values):
            for k, v in variant.items():
                try:
                    override(k, v)
                except (ValueError, TypeError) as exc:
                    problem(f"values[{i}]", f"{k!r}: {exc}")
                    return None
    name = raw.get("name", key.rsplit(".", 1)[-1].split("[")[0] if key else None)
    if not isinstance(name, str) or not _NAME.match(name):
        problem("name", f"expected an identifier naming the table's column, got {name!r}"
                        + (" (required without `key`)" if key is None else ""))
        return None
    if name in RESERVED:
        problem("name", f"{name!r} is a column of the table already (a metric or the point's status): "
                        "give the axis another name")
        return None
    labels = raw.get("labels")
    if labels is None:
        labels = [_label(v) if key is not None else f"{name}{i}" for i, v in enumerate(values)]
    elif (not isinstance(labels, list) or len(labels) != len(values)
          or not all(isinstance(x, str) and x for x in labels)):
        problem("labels", f"expected {len(values)} non-empty strings, one per value, got {labels!r}")
        return None
    if len(set(labels)) != len(labels):
        problem("labels", f"two values have the same label: {labels}")
        return None
    group = raw.get("group")
    if group is not None and (not isinstance(group, str) or not group):
        problem("group", f"expected a group name, got {group!r}")
        return None
    return Axis(name, key, tuple(values), tuple(labels), group)


def _values(value: Any) -> list[Any]:
    if not isinstance(value, list) or not value:
        raise ValueError(f"expected a non-empty list of values, got {value!r}")
    return list(value)


def _range(spec: Any) -> list[Any]:
    if not isinstance(spec, dict) or set(spec) != {"start", "stop", "step"}:
        raise ValueError(f"expected {{ start, stop, step }}, got {spec!r}")
    start, stop, step = spec["start"], spec["stop"], spec["step"]
    if not all(is_number(v) for v in (start, stop, step)) or step == 0 or (stop - start) / step < 0:
        raise ValueError(f"expected numbers with a step that goes from start to stop, got {spec!r}")
    n = int(math.floor((stop - start) / step + 1e-9)) + 1
    if n > 10000:
        raise ValueError(f"{n} values: more than 10000")
    integer = all(isinstance(v, int) for v in (start, stop, step))
    return [start + i * step if integer else round(start + i * step, 12) for i in range(n)]


def _random(spec: Any) -> list[Any]:
    """Seeded draws (numpy's default generator): the same file gives the same points on every machine."""
    if not isinstance(spec, dict):
        raise ValueError(f"expected {{ dist, low, high, n, seed }}, got {spec!r}")
    dist = spec.get("dist", "uniform")
    if dist not in DISTRIBUTIONS:
        raise ValueError(f"dist: expected one of {', '.join(DISTRIBUTIONS)}, got {dist!r}"
                         + _hint(dist, list(DISTRIBUTIONS)))
    wanted = {"normal": {"mean", "std"}}.get(dist, {"low", "high"}) | {"n", "seed"}
    allowed = wanted | {"dist"}
    extra, missing = set(spec) - allowed, wanted - set(spec)
    if extra or missing:
        raise ValueError(f"{dist}: needs {', '.join(sorted(wanted))}"
                         + (f"; unknown {', '.join(sorted(extra))}" if extra else "")
                         + (f"; missing {', '.join(sorted(missing))}" if missing else ""))
    n, seed = spec["n"], spec["seed"]
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= 10000:
        raise ValueError(f"n: expected an integer in 1..10000, got {n!r}")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed: expected an integer >= 0, got {seed!r}")
    rng = np.random.default_rng(seed)
    if dist == "normal":
        mean, std = spec["mean"], spec["std"]
        if not is_number(mean) or not is_number(std) or std <= 0:
            raise ValueError(f"normal: expected numbers mean and std > 0, got {mean!r}, {std!r}")
        return [float(v) for v in rng.normal(mean, std, n)]
    low, high = spec["low"], spec["high"]
    if not is_number(low) or not is_number(high) or not low < high or (dist == "loguniform" and low <= 0):
        raise ValueError(f"{dist}: expected numbers low < high{' (> 0)' if dist == 'loguniform' else ''}, "
                         f"got {low!r}, {high!r}")
    if dist == "integers":
        if not isinstance(low, int) or not isinstance(high, int):
            raise ValueError(f"integers: expected integer low and high, got {low!r}, {high!r}")
        return [int(v) for v in rng.integers(low, high, n, endpoint=True)]
    if dist == "loguniform":
        return [float(v) for v in np.exp(rng.uniform(math.log(low), math.log(high), n))]
    return [float(v) for v in rng.uniform(low, high, n)]


def _label(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (int, str)):
        return str(value)
    if isinstance(value, list):
        return " ".join(_label(v) for v in value) or "[]"
    return toml_literal(value)


def _check_groups(t: Table, axes: list[Axis]) -> None:
    groups: dict[str, list[Axis]] = {}
    for a in axes:
        if a.group:
            groups.setdefault(a.group, []).append(a)
    for name, members in groups.items():
        lengths = {a.name: len(a.values) for a in members}
        if len(set(lengths.values())) > 1:
            t.problem("axis", f"the axes of group {name!r} zip together and need one length, got {lengths}")


def _plots(t: Table, axes: list[Axis]) -> Plots:
    t.unknown_keys(PLOT_KEYS)
    names = [a.name for a in axes]
    plots = Plots()

    def axis_name(sub: Table, key: str, required: bool = True) -> str | None:
        value = sub.get(key)
        if value is None and not required:
            return None
        if value not in names:
            sub.problem(key, f"expected the name of an axis ({', '.join(names)}), got {value!r}"
                        + _hint(value, names))
            return None
        return value

    if "outcome_map" in t:
        m = t.sub("outcome_map", "a table { x = AXIS, y = AXIS }")
        m.unknown_keys(("x", "y"))
        x, y = axis_name(m, "x"), axis_name(m, "y")
        if m.ok and x == y:
            m.problem("y", "the map needs two different axes")
        if m.ok:
            plots.outcome_map = (x, y)
    if "curves" in t:
        c = t.sub("curves", "a table { x = AXIS, by = AXIS }")
        c.unknown_keys(("x", "by"))
        x, by = axis_name(c, "x"), axis_name(c, "by", required=False)
        if c.ok and x == by:
            c.problem("by", "the series axis must differ from x")
        if c.ok:
            plots.curves = (x, by)
    return plots


# -- points -------------------------------------------------------------------------------------------
def make_points(axes: list[Axis], combine: str, constants: tuple[Override, ...] = ()) -> list[Point]:
    """The sweep's points in order: a product over the groups (an ungrouped axis is a group of its own;
    the axes of one group zip), or one zip of every axis."""
    if combine == "zip":
        blocks = [axes]
    else:
        blocks, seen = [], {}
        for a in axes:
            if a.group is None:
                blocks.append([a])
            elif a.group in seen:
                seen[a.group].append(a)
            else:
                seen[a.group] = [a]
                blocks.append(seen[a.group])
    ranges = [range(len(block[0].values)) for block in blocks]
    points = []
    for index, combo in enumerate(itertools.product(*ranges)):
        chosen = {a.name: i for block, i in zip(blocks, combo) for a in block}
        ordered = [(a, chosen[a.name]) for a in axes]
        items = list(constants) + [override(k, v) for a, i in ordered for k, v in a.overrides(i)]
        params = {a.name: a.column(i) for a, i in ordered}
        labels = {a.name: a.labels[i] for a, i in ordered}
        pid = point_id(items)
        points.append(Point(index, params, labels, tuple(items), pid, folder_name(labels, pid)))
    return points


def point_id(items: list[Override]) -> str:
    """12 hex digits of a hash of the overrides (key and value, in order)."""
    text = json.dumps([[o.key, o.value] for o in items], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def folder_name(labels: dict[str, str], pid: str, limit: int = 80) -> str:
    """`ev_speed=25mph_loss=0.1-<id>`: the parameters, made file-name safe and cut to `limit`, then the id."""
    text = "_".join(f"{k}={v}" for k, v in labels.items())
    text = re.sub(r"[^A-Za-z0-9._=+\-]+", "", text.replace(" ", "-"))[:limit].strip("._-")
    return f"{text}-{pid}" if text else pid
