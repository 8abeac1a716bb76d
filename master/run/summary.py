"""The short report printed after `v2i run`."""
from __future__ import annotations

import csv

import json

from master.run.cosim import RunResult
from master.run.metrics import METRICS
from master.run.recorder import TIMESERIES
from master.run.verdict import realtime_warning, verdict_lines


def _metrics(result: RunResult) -> dict:
    try:
        return json.loads((result.run_dir / METRICS).read_text()) if result.metadata.get("metrics") else {}
    except (OSError, ValueError):
        return {}


def format_summary(result: RunResult, max_rows: int = 16) -> str:
    meta = result.metadata
    rtf = meta.get("rtf", {}).get("achieved")
    lines = [
        f"run {meta['scenario']}: {result.status} — {meta.get('steps_done', 0)} steps "
        f"({meta['mode']}, {meta['ordering']}, step {meta['step_s']} s) "
        f"to t = {meta.get('sim_time_reached_s', 0):.3f} s in {meta.get('wall_time_s', 0):.3f} s wall"
        + (f", RTF {rtf:.1f}" if rtf else ""),
    ]
    rt = meta.get("realtime")
    if rt and rt.get("lag_s"):
        lag = rt["lag_s"]
        if lag["n"]:
            lines.append(f"  realtime lag p50 {lag['p50'] * 1e3:.3f} ms, p99 {lag['p99'] * 1e3:.3f} ms, "
                         f"max {lag['max'] * 1e3:.3f} ms; deadline misses {rt['deadline_misses']}")
        nice = rt.get("loop_nice") or {}
        if nice.get("note"):
            lines.append(f"  loop priority (time.loop_nice = {nice['asked']}): {nice['note']}")
    if meta.get("stop_reason"):
        lines.append(f"  stopped: {meta['stop_reason']}")
    metrics = _metrics(result)
    for line in verdict_lines(metrics):
        lines.append(f"  {line}")
    rt_warning = realtime_warning(meta)
    if rt_warning:
        lines.append(f"  WARNING: {rt_warning}")
    lines.append(f"  run folder: {result.run_dir}")
    path = result.run_dir / TIMESERIES
    if not path.exists():
        return "\n".join(lines)
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if len(rows) < 2:
        return "\n".join(lines)
    header, data = rows[0], rows[1:]
    lines.append(f"  {'variable':24s} {'initial':>12s} {'final':>12s} {'min':>12s} {'max':>12s}")
    for c, name in enumerate(header[1:max_rows + 1], start=1):
        try:
            col = [float(r[c]) for r in data]
        except ValueError:
            continue
        lines.append(f"  {name:24s} {col[0]:12.4g} {col[-1]:12.4g} {min(col):12.4g} {max(col):12.4g}")
    if len(header) - 1 > max_rows:
        lines.append(f"  … {len(header) - 1 - max_rows} more columns in {TIMESERIES}")
    return "\n".join(lines)
