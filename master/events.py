"""The run's event log: one JSON object per line in `events.jsonl`, flushed as written.

Bridges log what happens to messages (sent, dropped, delivered, rejected) with
their simulation times; a crash loses at most the line being written. Safe to
call from bridge threads.
"""
from __future__ import annotations

import json
import threading
from collections import Counter
from pathlib import Path
from typing import Any

EVENTS = "events.jsonl"


class EventLog:
    """`EventLog(run_dir)` appends to run_dir/events.jsonl; `name` picks another file (a bridge's own log)."""

    def __init__(self, run_dir: Path | None, name: str = EVENTS, mode: str = "a"):
        self._lock = threading.Lock()
        self._file = open(Path(run_dir) / name, mode) if run_dir is not None else None
        self.counts: Counter[str] = Counter()

    def __call__(self, event: dict[str, Any]) -> None:
        line = json.dumps(event, default=str, separators=(",", ":"))
        with self._lock:
            self.counts[event.get("event", "?")] += 1
            if self._file is not None and not self._file.closed:
                self._file.write(line + "\n")
                self._file.flush()

    def close(self) -> dict[str, int]:
        with self._lock:
            if self._file is not None and not self._file.closed:
                self._file.close()
        return dict(self.counts)
