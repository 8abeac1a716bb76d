"""The run folder: resolved scenario, incremental time series, timing, metadata.

Rows go to disk at least every FLUSH_S of wall time (and at the end), so a
crash or `kill -9` loses at most the rows of the last FLUSH_S of wall time
(0.05 s: five 10 ms steps of a realtime run, more of a fast lockstep one) and
never leaves a row torn in the middle of the file; flushing every row cost
the loop several microseconds per step. A row is kept as its values until
the flush, which formats the block in one go: the text is what the csv
module writes for numbers (a float as repr(), the shortest exact text; CRLF
line ends), made by one %-format per row in about two thirds of
csv.writer's time (a row of 10 compiled FMUs, 31 values with 17-digit
floats: 5 us against 7.6 us; repr() of the floats is most of what is left).
The master records only numbers, a column's type fixed by its FMU getter; a
first row holding anything else (None, text) is written by the csv module
throughout.
`metadata.json` is written at the start (status "running") and rewritten at
the end with the outcome and statistics.
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
# values whose %r is the text the csv module writes for them (csv: repr() of a float, str() of the rest)
_NUMBERS = frozenset((float, int, bool))


class RunRecorder:
    def __init__(self, run_dir: Path, columns: Sequence[str], clock=time.monotonic):
        self.run_dir = Path(run_dir)
        self.columns = ["time", *columns]
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._ts_file = open(self.run_dir / TIMESERIES, "w", newline="")
        self._ts = csv.writer(self._ts_file)
        self._ts.writerow(self.columns)  # names may need quoting ("a[1,2]"): the csv module
        self._pending: list[tuple] = []  # rows not yet formatted: (t, *values)
        self._written = 0  # rows formatted and handed to the file
        self._row_format: str | None = None  # "%r,%r,...\r\n" when the rows are numbers (set by the first row)
        self._clock = clock
        self._flushed = -math.inf  # the first row goes out at once: the file shows the run under way

    def write_resolved(self, resolved: dict[str, Any]) -> None:
        import tomli_w

        (self.run_dir / RESOLVED).write_text(tomli_w.dumps(_toml_safe(resolved)))

    def write_metadata(self, metadata: dict[str, Any]) -> None:
        tmp = self.run_dir / (METADATA + ".tmp")
        tmp.write_text(json.dumps(metadata, indent=2, default=str) + "\n")
        os.replace(tmp, self.run_dir / METADATA)  # never a half-written file

    @property
    def rows(self) -> int:
        """Rows recorded so far (on disk or still kept)."""
        return self._written + len(self._pending)

    def row(self, t: float, values: Sequence[Any]) -> None:
        self._pending.append((t, *values))
        now = self._clock()
        if now - self._flushed >= FLUSH_S:
            self.flush(now)

    def flush(self, now: float | None = None) -> None:
        """Everything written so far to the OS (which keeps it if this process is killed)."""
        self._write_pending()
        self._ts_file.flush()
        self._flushed = self._clock() if now is None else now

    def _write_pending(self) -> None:
        """The rows kept since the last flush, formatted as one block (one write)."""
        rows = self._pending
        if not rows:
            return
        self._pending = []
        self._written += len(rows)
        if self._row_format is None:
            numbers = all(type(v) in _NUMBERS for v in rows[0]) and len(rows[0]) == len(self.columns)
            self._row_format = ",".join(["%r"] * len(self.columns)) + "\r\n" if numbers else ""
        fmt = self._row_format
        if fmt:
            try:
                text = "".join([fmt % r for r in rows])
            except TypeError:  # a row of another length: the csv module writes whatever it is given
                self._row_format = ""
            else:
                self._ts_file.write(text)
                return
        self._ts.writerows(rows)

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
            self._write_pending()
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
