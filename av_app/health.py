"""Health of the AV app: counters, latency samples, the periodic stats line and the exit summary."""
from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np


def pct(samples, qs=(50, 99)) -> dict[str, float | int | None]:
    """{p50, p99, max, n} of samples (ms or whatever unit they are in)."""
    a = np.asarray(list(samples), float)
    if len(a) == 0:
        return {**{f"p{q}": None for q in qs}, "max": None, "n": 0}
    return {**{f"p{q}": float(np.percentile(a, q)) for q in qs}, "max": float(a.max()), "n": int(len(a))}


class Health:
    def __init__(self):
        self.garbage: Counter = Counter()  # bad input by source: "lidar", "gnss", "v2x", "trace", ...
        self.counts: Counter = Counter()  # events: scans, fixes, statuses, commands, ...
        self.stage3_sim_ms: list[float] = []  # AIR_ARRIVAL -> CAN_COMMAND in simulated time
        self.stage3_compute_ms: list[float] = []  # verify+decode+fuse of the frame + plan + CAN send, wall
        self.plan_ms: list[float] = []
        self.cluster_ms: list[float] = []
        self.objects_by_source: Counter = Counter()  # of the last plan
        self.decision = "init"
        self.cause = ""
        self.decisions: Counter = Counter()  # plans per decision
        self.first: dict[str, float] = {}  # first times of notable events (sim s)
        self.errors: Counter = Counter()  # internal errors by type (should stay empty)
        self.self_bsms: Counter = Counter()  # distinct BSMs recognised as the ego, by rule (av_app.selfid)

    def mark(self, event: str, t: float) -> None:
        self.first.setdefault(event, t)

    def line(self, name: str, t: float | None, obu, can) -> str:
        rej = ",".join(f"{k}={v}" for k, v in sorted(obu.rejected.items())) or "0"
        src = ",".join(f"{k}={v}" for k, v in sorted(self.objects_by_source.items())) or "none"
        s3 = pct(self.stage3_compute_ms)
        fmt = (lambda v: f"{v:.2f}" if v is not None else "-")
        return (f"{name}: t={t if t is not None else '-'} v2x rx={obu.received} ok={sum(obu.accepted.values())} "
                f"rejected[{rej}] self={sum(self.self_bsms.values())} objects[{src}] decision={self.decision}"
                f"{'(' + self.cause + ')' if self.cause else ''} stage3 p50={fmt(s3['p50'])} "
                f"p99={fmt(s3['p99'])} ms can cmds={can.sent.get('AV_Command', 0) if can else 0}")

    def summary(self) -> dict[str, Any]:
        return {"counts": dict(self.counts), "garbage": dict(self.garbage), "errors": dict(self.errors),
                "decision": self.decision, "cause": self.cause, "decisions": dict(self.decisions),
                "objects_by_source": dict(self.objects_by_source), "first_s": dict(self.first),
                "v2x_self_bsms": dict(self.self_bsms),
                "stage3_sim_ms": pct(self.stage3_sim_ms), "stage3_compute_ms": pct(self.stage3_compute_ms),
                "plan_ms": pct(self.plan_ms), "lidar_ms": pct(self.cluster_ms)}
