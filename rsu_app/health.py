"""What the RSU app tells its operator: a stats line every few seconds (stderr), a JSON summary at exit (stdout).

Stage figures are given twice, because they answer two questions:
`compute_ms` is what this computer spent (wall clock: detect + project for
stage 1, encode + sign for stage 2), `charged_ms` what the run charged in
simulated time (the latency policy or the hardware profile).
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np


def percentiles_ms(values) -> dict[str, float | int | None]:
    a = np.asarray(list(values), float) * 1000.0
    if a.size == 0:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    return {"p50": round(float(np.percentile(a, 50)), 3), "p99": round(float(np.percentile(a, 99)), 3),
            "max": round(float(a.max()), 3), "n": int(a.size)}


class Health:
    def __init__(self, app, every_s: float, stream=sys.stderr):
        self.app, self.every_s, self.stream = app, every_s, stream
        self._last = time.monotonic()
        self.started = time.monotonic()

    def maybe_report(self) -> None:
        if self.every_s <= 0:
            return
        now = time.monotonic()
        if now - self._last >= self.every_s:
            self._last = now
            print(self.line(), file=self.stream, flush=True)

    def line(self) -> str:
        s = self.app.snapshot()
        st1, st2 = s["stage1"]["compute_ms"], s["stage2"]["compute_ms"]
        fmt = lambda v: "-" if v is None else f"{v:.1f}"  # noqa: E731
        cam = s["camera"]
        return (f"{s['name']}: t={s['t_sim']:.2f} frames {cam['received']} (busy-dropped {s['frames_dropped_busy']}, "
                f"bad {cam['bad']}, late {cam['late']}) detections {s['detections']} tracks {s['confirmed_tracks']} "
                f"BSMs {s['bsm_sent']} SPaT {s['spat_sent']} MAP {s['map_sent']} | stage1 p50/p99 "
                f"{fmt(st1['p50'])}/{fmt(st1['p99'])} ms, stage2 {fmt(st2['p50'])}/{fmt(st2['p99'])} ms")


def clean(x):
    """JSON-safe: NaN/inf -> None, tuples -> lists, bytes -> hex."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, set)):
        return [clean(v) for v in x]
    if isinstance(x, bytes):
        return x.hex()
    if isinstance(x, np.generic):
        return x.item()
    return x
