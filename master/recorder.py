"""The run folder: resolved scenario, incremental time series, timing, metadata.

Rows go to disk at least every FLUSH_S of wall time (and at the end), so a
crash or `kill -9` loses at most the rows of the last FLUSH_S of wall time
(0.05 s: five 10 ms steps of a realtime run, more of a fast lockstep one) and
never leaves a row torn in the middle of the file; flushing every row cost
the loop several microseconds per step. `metadata.json` is written at the
start (status "running") and rewritten at the end with the outcome and
statistics.
"""
from __future__ import annotations

import csv
import json
import math
import os
import time
from pathlib import Path
from typing import Any, Sequence

TIMESERIES = "timeseries.csv"
TIMING = "timing.csv"
METADATA = "metadata.json"
RESOLVED = "scenario.resolved.toml"
FLUSH_S = 0.05  # wall seconds: the most recorded time a killed run can lose


class RunRecorder:
    def __init__(self, run_dir: Path, columns: Sequence[str], clock=time.monotonic):
        self.run_dir = Path(run_dir)
        self.columns = ["time", *columns]
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._ts_file = open(self.run_dir / TIMESERIES, "w", newline="")
        self._ts = csv.writer(self._ts_file)
        self._ts.writerow(self.columns)
        self.rows = 0
        self._clock = clock
        self._flushed = clock()

    def write_resolved(self, resolved: dict[str, Any]) -> None:
        import tomli_w

        (self.run_dir / RESOLVED).write_text(tomli_w.dumps(_toml_safe(resolved)))

    def write_metadata(self, metadata: dict[str, Any]) -> None:
        tmp = self.run_dir / (METADATA + ".tmp")
        tmp.write_text(json.dumps(metadata, indent=2, default=str) + "\n")
        os.replace(tmp, self.run_dir / METADATA)  # never a half-written file

    def row(self, t: float, values: Sequence[Any]) -> None:
        self._ts.writerow([t, *values])  # csv writes a float as repr() does: the shortest exact text
        self.rows += 1
        now = self._clock()
        if now - self._flushed >= FLUSH_S or self.rows == 1:  # the first row at once: the run is under way
            self.flush(now)

    def flush(self, now: float | None = None) -> None:
        """Everything written so far to the OS (which keeps it if this process is killed)."""
        self._ts_file.flush()
        self._flushed = self._clock() if now is None else now

    def write_timing(self, start: float, step: float, compute_s: Sequence[float], lag_s: Sequence[float],
                     misses: Sequence[int]) -> None:
        """timing.csv from the loop's per-step arrays, once at the end (`lag_s` empty in lockstep): a row per
        step written in the loop cost it about 2 us a step; a killed run has no timing.csv."""
        with open(self.run_dir / TIMING, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["step", "time", "compute_s", "lag_s", "deadline_miss"])
            for k, c in enumerate(compute_s):
                lag = f"{lag_s[k]:.9f}" if k < len(lag_s) else ""
                w.writerow([k, repr(start + k * step), f"{c:.9f}", lag, misses[k] if k < len(misses) else 0])

    def close(self) -> None:
        if not self._ts_file.closed:
            self._ts_file.flush()
            self._ts_file.close()

    def write_parquet(self) -> str | None:
        """Parquet copy of the CSV when pyarrow is installed; returns the reason when skipped."""
        try:
            import pyarrow.csv as pacsv
            import pyarrow.parquet as pq
        except ImportError:
            return "pyarrow not installed"
        table = pacsv.read_csv(self.run_dir / TIMESERIES)
        pq.write_table(table, self.run_dir / "timeseries.parquet")
        return None


def _toml_safe(value):
    """TOML has no null and no NaN-free guarantee: drop None, keep the rest."""
    if isinstance(value, dict):
        return {k: _toml_safe(v) for k, v in value.items() if v is not None}
    if isinstance(value, list):
        return [_toml_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value
