"""The design-space table of a DSE sweep (dse.md): the seed paper's Table 2 rows beside the sweep's points.

The seed paper compared RSU computers by detection rate and price only (Table 2,
ANCHORS I7). A DSE sweep runs the whole case study on each platform (its
inference time emulated, or the detector measured on this machine) and under
each latency policy, so the table adds what the question is about: does the
vehicle still avoid the collision, with what gap, and at what end-to-end
latency. Its sweep file says which axis is the platform and where the costs are:

    [sweep.dse]
    platform = "rsu"            # the axis whose labels name the platforms
    policy = "policy"           # optional: the axis of the latency policy
    costs = "costs.toml"        # relative to the sweep file, editable

and the costs file holds, per platform label::

    [platforms.cpu-i7]
    label = "Intel i7 CPU, 8 cores"
    kind = "emulated"           # emulated (a fixed inference time) or measured (the detector on this machine)
    paper_fps = 0.27            # a row of the paper's own (omit for platforms it did not have)
    cost_usd = 277.99           # omit when unknown: the table says "–"
    source = "seed paper Table 2 (ANCHORS I7)"
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

from master.sweep.spec import Point, SweepSpec

DSE_TABLE = "dse.md"
REQUIRED_FPS = 10.0  # ANCHORS I7: 10 FPS to keep up with 10 Hz BSMs
DSE_KEYS = ("platform", "policy", "costs")


def check_dse(spec: SweepSpec) -> list[str]:
    """Problems of [sweep.dse] (key: reason), the costs file included."""
    dse, names = spec.dse, [a.name for a in spec.axes]
    if not dse:
        return []
    problems = [f"sweep.dse.{k}: unknown key (expected one of: {', '.join(DSE_KEYS)})" for k in dse
                if k not in DSE_KEYS]
    for key in ("platform", "policy"):
        value = dse.get(key)
        if (key == "platform" or value is not None) and value not in names:
            problems.append(f"sweep.dse.{key}: expected the name of an axis ({', '.join(names)}), got {value!r}")
    try:
        read_costs(spec)
    except ValueError as exc:
        problems.append(f"sweep.dse.costs: {exc}")
    return problems


def read_costs(spec: SweepSpec) -> dict[str, dict[str, Any]]:
    """The platforms table of the costs file ({} without one); ValueError when unreadable."""
    name = spec.dse.get("costs")
    if name is None:
        return {}
    path = spec.path.parent / str(name)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path} is not valid TOML: {exc}") from None
    platforms = raw.get("platforms", {})
    if not isinstance(platforms, dict) or not all(isinstance(v, dict) for v in platforms.values()):
        raise ValueError(f"{path}: expected [platforms.NAME] tables")
    for pname, entry in platforms.items():
        for key in ("cost_usd", "paper_fps"):
            value = entry.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0):
                raise ValueError(f"{path}: platforms.{pname}.{key}: expected a number >= 0, got {value!r}")
    return platforms


def write_dse(spec: SweepSpec, points: list[Point], table: list[dict[str, Any]], folder: Path) -> Path:
    """dse.md in the sweep folder."""
    costs = read_costs(spec)
    platform_axis, policy_axis = spec.dse["platform"], spec.dse.get("policy")
    head = ["platform", "where", "latency policy", "FPS", f"≥ {REQUIRED_FPS:g} FPS", "stage ① p50 / p99 (ms)",
            "E2E p50 / p99 (ms)", "collision", "min gap (m)", "cost (USD)"]
    lines = [f"# Design-space exploration: {spec.name}", "",
             "The seed paper's Table 2 (ANCHORS I7: detection rate and price of three RSU computers) beside "
             "this sweep's runs of the whole case study on each platform. FPS of a run = 1000 / stage ① p50 "
             "(camera frame → objects tracked, simulated time); an *emulated* platform charges its fixed "
             "inference time, a *measured* one the detector's real compute time on the machine that ran the "
             "point (under the `fixed` policy stage ① is the scenario's configured value instead). "
             f"{REQUIRED_FPS:g} FPS keeps up with 10 Hz BSMs (I7). Costs: {spec.dse.get('costs', '(none)')}, "
             "editable.", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, entry in costs.items():
        fps = entry.get("paper_fps")
        if fps is None:
            continue
        lines.append(_row([entry.get("label", name), entry.get("source", "seed paper Table 2"), "–", _num(fps),
                           _yes(fps >= REQUIRED_FPS), "–", "–", "–", "–", _money(entry.get("cost_usd"))]))
    cpus = sorted({f"{r.get('host')}: {r.get('cpu')}" for r in table if r.get("cpu")})
    for p, row in zip(points, table):
        name = p.labels[platform_axis]
        entry = costs.get(name, {})
        kind = entry.get("kind", "emulated" if entry.get("paper_fps") is not None else "measured")
        where = "this sweep, emulated" if kind == "emulated" else "this sweep, measured"
        policy = p.labels[policy_axis] if policy_axis else (row.get("latency_policy") or "–")
        if row.get("status") != "ok":
            error = str(row.get("error") or row.get("status")).splitlines()[0][:80]
            lines.append(_row([entry.get("label", name), where, policy, "–", "–", "–", "–",
                               f"{row.get('status')}: {error}", "–", _money(entry.get("cost_usd"))]))
            continue
        s50, s99 = _f(row.get("latency_ms.stage1.p50")), _f(row.get("latency_ms.stage1.p99"))
        e50, e99 = _f(row.get("latency_ms.e2e.p50")), _f(row.get("latency_ms.e2e.p99"))
        fps = 1000.0 / s50 if s50 else None
        lines.append(_row([entry.get("label", name), where, policy, _num(fps),
                           _yes(fps >= REQUIRED_FPS) if fps is not None else "–",
                           f"{_num(s50)} / {_num(s99)}", f"{_num(e50)} / {_num(e99)}",
                           _yes(row.get("collision")) if row.get("collision") is not None else "–",
                           _num(_f(row.get("min_gap_m"))), _money(entry.get("cost_usd"))]))
    if cpus:
        lines += ["", "Measured on: " + "; ".join(cpus) + "."]
    path = Path(folder) / DSE_TABLE
    path.write_text("\n".join(lines) + "\n")
    return path


def _row(cells: list[Any]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _f(value: Any) -> float | None:
    if value is None or value == "" or isinstance(value, bool):
        return None
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None


def _num(value: float | None) -> str:
    if value is None:
        return "–"
    return f"{value:.3g}" if abs(value) < 100 else f"{value:.0f}"


def _money(value: Any) -> str:
    return "–" if value is None else f"{float(value):,.2f}"


def _yes(flag: Any) -> str:
    return "yes" if flag else "no"
