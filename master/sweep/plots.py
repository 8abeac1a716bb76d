"""The sweep's pictures (matplotlib, written beside the table), chosen in the sweep file's [sweep.plots].

* `outcome_map.png`: one cell per pair of values of two axes; the cell's colour
  is the smallest gap between the vehicles (metres, colour bar), its mark says
  collision (✕, red) or avoided (○); a cell over several points (a third axis)
  counts the collisions ("2/4") and shows the smallest gap; a cell with a
  failed point only is grey with "failed".
* `curves.png`: the min gap and the end-to-end latency p99 against one axis,
  a line per value of a second (`by`), collisions marked ✕.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from master.sweep.spec import Point, SweepSpec

OUTCOME_MAP = "outcome_map.png"
CURVES = "curves.png"
FIGSIZE = (8.0, 5.0)  # inches at DPI: 800 x 500 pixels
DPI = 100


def write_plots(spec: SweepSpec, points: list[Point], table: list[dict[str, Any]], folder: Path) -> list[Path]:
    """The plots the sweep file asks for; the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    written = []
    if spec.plots.outcome_map:
        x, y = spec.plots.outcome_map
        written.append(outcome_map(spec, points, table, x, y, Path(folder) / OUTCOME_MAP))
    if spec.plots.curves:
        x, by = spec.plots.curves
        written.append(curves(spec, points, table, x, by, Path(folder) / CURVES))
    return written


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or value is None or value == "":
        return None
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None


def outcome_map(spec: SweepSpec, points: list[Point], table: list[dict[str, Any]], x: str, y: str,
                path: Path) -> Path:
    import matplotlib.pyplot as plt
    from matplotlib import colors

    xs, ys = list(spec.axis(x).labels), list(spec.axis(y).labels)
    cells: dict[tuple[int, int], list[dict[str, Any]]] = {}
    for p, row in zip(points, table):
        cells.setdefault((xs.index(p.labels[x]), ys.index(p.labels[y])), []).append(row)
    gaps = [g for rows in cells.values() for r in rows if r["status"] == "ok"
            for g in [_number(r.get("min_gap_m"))] if g is not None]
    vmax = max(gaps + [1.0])
    norm = colors.Normalize(vmin=0.0, vmax=vmax)
    cmap = plt.get_cmap("viridis")
    fig, ax = plt.subplots(figsize=FIGSIZE, dpi=DPI)
    for (i, j), rows in cells.items():
        ok = [r for r in rows if r["status"] == "ok"]
        if not ok:
            ax.add_patch(plt.Rectangle((i - 0.5, j - 0.5), 1, 1, color="0.8"))
            ax.text(i, j, "failed" if any(r["status"] == "failed" for r in rows) else "pending",
                    ha="center", va="center", fontsize=8)
            continue
        cell_gaps = [g for r in ok for g in [_number(r.get("min_gap_m"))] if g is not None]
        gap = min(cell_gaps) if cell_gaps else None
        ax.add_patch(plt.Rectangle((i - 0.5, j - 0.5), 1, 1,
                                   color=cmap(norm(gap)) if gap is not None else "0.9"))
        hits = sum(1 for r in ok if r.get("collision") is True)
        mark = "✕" if hits else "○"
        count = f" {hits}/{len(ok)}" if len(ok) > 1 else ""
        text = f"{mark}{count}\n{gap:.2f} m" if gap is not None else f"{mark}{count}"
        ax.text(i, j, text, ha="center", va="center", fontsize=9, fontweight="bold",
                color="red" if hits else "white" if gap is not None and norm(gap) < 0.6 else "black")
    ax.set_xlim(-0.5, len(xs) - 0.5)
    ax.set_ylim(-0.5, len(ys) - 0.5)
    ax.set_xticks(range(len(xs)), xs, rotation=30 if max(map(len, xs)) > 6 else 0, ha="right" if max(
        map(len, xs)) > 6 else "center")
    ax.set_yticks(range(len(ys)), ys)
    ax.set_xlabel(x)
    ax.set_ylabel(y)
    ax.set_title(f"{spec.name}: ✕ collision, ○ avoided; colour: min gap between footprints")
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, label="min gap (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def curves(spec: SweepSpec, points: list[Point], table: list[dict[str, Any]], x: str, by: str | None,
           path: Path) -> Path:
    import matplotlib.pyplot as plt

    axis = spec.axis(x)
    numeric = axis.key is not None and all(_number(v) is not None for v in axis.values)
    position = {label: (float(axis.values[i]) if numeric else float(i)) for i, label in enumerate(axis.labels)}
    series: dict[str, list[tuple[float, dict[str, Any]]]] = {}
    for p, row in zip(points, table):
        if row["status"] != "ok":
            continue
        name = p.labels[by] if by else spec.name
        series.setdefault(name, []).append((position[p.labels[x]], row))
    fig, (top, bottom) = plt.subplots(2, 1, figsize=FIGSIZE, dpi=DPI, sharex=True)
    order = list(spec.axis(by).labels) if by else [spec.name]
    for name in [n for n in order if n in series]:
        items = sorted(series[name], key=lambda item: item[0])
        xs = [item[0] for item in items]
        gap = [_number(r.get("min_gap_m")) for _, r in items]
        e2e = [_number(r.get("latency_ms.e2e.p99")) for _, r in items]
        line, = top.plot(xs, [math.nan if g is None else g for g in gap], marker="o", label=name)
        hit = [(xv, g or 0.0) for xv, g, (_, r) in zip(xs, gap, items) if r.get("collision") is True]
        if hit:
            top.plot(*zip(*hit), linestyle="none", marker="x", markersize=10, color="red")
        bottom.plot(xs, [math.nan if v is None else v for v in e2e], marker="o", color=line.get_color())
    if not bottom.lines or all(all(math.isnan(v) for v in ln.get_ydata()) for ln in bottom.lines):
        bottom.text(0.5, 0.5, "no end-to-end latency in these runs (no apps)", transform=bottom.transAxes,
                    ha="center", va="center", color="0.4")
    top.set_ylabel("min gap (m)")
    top.set_title(f"{spec.name}: outcome against {x}" + (" (✕ collision)" if series else ""))
    bottom.set_ylabel("E2E p99 (ms)")
    bottom.set_xlabel(x)
    if not numeric:
        bottom.set_xticks(range(len(axis.labels)), axis.labels)
    if by and series:
        top.legend(title=by, fontsize=8)
    for a in (top, bottom):
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path
