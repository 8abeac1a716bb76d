"""The sweep's record of its points (points.jsonl) and its table (sweep.csv, sweep.parquet).

`points.jsonl` is the ledger: one line per finished attempt of a point, with
what `run_point` returned (status, error, wall time, the run's metrics.json),
appended as each point ends, so an interrupted sweep loses nothing that
finished. A re-run reads it: a point whose last attempt is `ok` is skipped; a
`failed` one is run again (its failure may have been the machine's: a port, a
timeout under load), its old folder replaced.

The table has one row per point of the sweep as it is now defined (points of an
earlier definition stay in the ledger, not in the table), in the sweep's order:

    point, folder, <one column per axis>, status (ok, failed, pending), error, run_status (the run's
    own: completed, stopped), wall_s, host, cpu,
    collision, first_collision_s, min_gap_m, min_ttc_s, pet_s,
    latency_ms.e2e.p50, latency_ms.e2e.p99, latency_ms.stage1.p50, ... (every field of
    metrics.json flattened with dots, e.g. pdr.rsu->cav.pdr, aoi_ms.cav<-ev.p99)

The metrics' names are metrics.json's own (a contract: README, "metrics.json").
"""
from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any, Iterable

from master.sweep.spec import Point

LEDGER = "points.jsonl"
CSV = "sweep.csv"
PARQUET = "sweep.parquet"
FIRST_METRICS = ("collision", "first_collision_s", "min_gap_m", "min_ttc_s", "pet_s",
                 "latency_ms.e2e.p50", "latency_ms.e2e.p99", "latency_ms.stage1.p50", "latency_ms.stage1.p99")
_SKIP = ("scenario", "status", "pairs", "first_collision")  # in the row already (status: as run_status), per-pair
                                                             # detail, or a nested duplicate


class Ledger:
    """points.jsonl of a sweep folder."""

    def __init__(self, folder: Path):
        self.path = Path(folder) / LEDGER

    def entries(self) -> list[dict[str, Any]]:
        from master.run.metrics import read_jsonl

        return read_jsonl(self.path)

    def latest(self) -> dict[str, dict[str, Any]]:
        """point id -> its last recorded attempt."""
        out: dict[str, dict[str, Any]] = {}
        for entry in self.entries():
            if isinstance(entry.get("id"), str):
                out[entry["id"]] = entry
        return out

    def finished(self) -> set[str]:
        """The ids of the points whose last attempt is ok (a re-run skips them)."""
        return {pid for pid, e in self.latest().items() if e.get("status") == "ok"}

    def append(self, entry: dict[str, Any]) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            f.write(json.dumps(entry, default=str) + "\n")
            f.flush()


def flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} -> {"a.b": 1}; lists become JSON text (a cell holds one value)."""
    out: dict[str, Any] = {}
    if isinstance(value, dict):
        for key, item in value.items():
            out.update(flatten(item, f"{prefix}.{key}" if prefix else str(key)))
    elif isinstance(value, list):
        out[prefix] = json.dumps(value)
    else:
        out[prefix] = value
    return out


def rows(points: Iterable[Point], latest: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per point (a point not run yet: status "pending")."""
    out = []
    for p in points:
        entry = latest.get(p.id, {})
        metrics = entry.get("metrics") or {}
        row: dict[str, Any] = {"point": p.id, "folder": p.folder, **p.params,
                               "status": entry.get("status", "pending"), "error": entry.get("error"),
                               "wall_s": entry.get("wall_s"), "host": entry.get("host"), "cpu": entry.get("cpu"),
                               "run_status": metrics.get("status") or entry.get("run_status")}
        row.update({k: v for k, v in flatten({k: v for k, v in metrics.items() if k not in _SKIP}).items()})
        out.append(row)
    return out


def columns(table: list[dict[str, Any]], points: list[Point]) -> list[str]:
    """Parameters and status first, then the headline metrics, then every other metric, sorted."""
    head = ["point", "folder", *(points[0].params if points else ()), "status", "error", "run_status", "wall_s",
            "host", "cpu"]
    seen = {k for row in table for k in row}
    rest = sorted(seen - set(head) - set(FIRST_METRICS))
    return head + [k for k in FIRST_METRICS if k in seen] + rest


def write_table(folder: Path, table: list[dict[str, Any]], points: list[Point]) -> list[Path]:
    """sweep.csv, and sweep.parquet when pyarrow is there; the paths written."""
    folder = Path(folder)
    cols = columns(table, points)
    path = folder / CSV
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
        writer.writeheader()
        for row in table:
            writer.writerow({k: _cell(row.get(k)) for k in cols})
    tmp.replace(path)
    written = [path]
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return written
    data = {k: _column(table, k) for k in cols}
    pq.write_table(pa.table(data), folder / PARQUET)
    written.append(folder / PARQUET)
    return written


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    return value


def _column(table: list[dict[str, Any]], key: str) -> list[Any]:
    """A column with one type for parquet: numbers and bools as they are, anything mixed as text."""
    values = [row.get(key) for row in table]
    kinds = {type(v) for v in values if v is not None}
    if kinds <= {bool} or kinds <= {int} or kinds <= {float, int} or kinds <= {str}:
        if kinds == {float, int}:
            return [None if v is None else float(v) for v in values]
        return values
    return [None if v is None else str(v) for v in values]
