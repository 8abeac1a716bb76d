"""Wall-clock pacing of realtime runs, with an explicit overrun policy.

Step k is scheduled to start at T_k = t0 + k * period (+ any slip). The pacer
sleeps until shortly before T_k and spins the rest on the monotonic
`perf_counter`, which keeps the start lag (jitter) well under a millisecond.
A step that ends after the next slot began is a deadline miss; the policy
decides what follows:

* `catch-up` keep the schedule; late steps run back to back until on time;
* `slip`     shift the whole schedule by the overrun (no bursts, drifts behind);
* `skip`     drop the missed slots and keep the schedule's phase;
* `abort`    end the run with DeadlineMissError.
"""
from __future__ import annotations

import errno
import math
import os
import threading
import time

from master.errors import DeadlineMissError


class Pacer:
    def __init__(self, period: float, policy: str = "catch-up", spin: float = 0.0015, clock=time.perf_counter):
        if period <= 0:
            raise ValueError(f"period must be > 0, got {period}")
        self.period, self.policy, self.spin, self.clock = period, policy, spin, clock
        self.t0 = 0.0
        self.shift = 0.0
        self.misses = 0
        self.skipped_slots = 0

    def start(self) -> None:
        self.t0 = self.clock()

    def scheduled(self, k: int) -> float:
        return self.t0 + self.shift + k * self.period

    def wait(self, k: int) -> float:
        """Block until slot k; returns the start lag (seconds late, >= 0)."""
        target = self.scheduled(k)
        remaining = target - self.clock()
        if remaining > self.spin:
            time.sleep(remaining - self.spin)
        while self.clock() < target:
            pass
        return self.clock() - target

    def finished(self, k: int, sim_time: float) -> bool:
        """Call when step k is done; applies the overrun policy. True if it missed its deadline."""
        now = self.clock()
        deadline = self.scheduled(k + 1)
        if now <= deadline:
            return False
        self.misses += 1
        overrun = now - deadline
        if self.policy == "abort":
            raise DeadlineMissError(
                f"realtime deadline missed at step {k} (t = {sim_time:.6g} s): the step ended "
                f"{overrun * 1e3:.3f} ms after the next slot began (overrun policy 'abort')")
        if self.policy == "slip":
            self.shift += overrun
        elif self.policy == "skip":
            slots = math.ceil(overrun / self.period)
            self.skipped_slots += slots
            self.shift += slots * self.period
        return True


def set_loop_nice(nice: int) -> dict:
    """Give the calling thread (the realtime loop's) the nice value `nice`; what happened, for metadata.json.

    On two cores the loop shares the CPU with the apps (and the sensor workers, which run under
    SCHED_IDLE): at the apps' priority, a step that woke while both apps computed waited for a core,
    and 1-1.5 % of the case study's steps at RTF 1 missed their deadlines; at nice -10 0.2-0.4 %.
    Only this thread: the apps and the bus's threads, started before, keep theirs. A value below the
    current one needs CAP_SYS_NICE (root); refused, the loop keeps its priority and says why.
    """
    tid = threading.get_native_id()
    try:
        before = os.getpriority(os.PRIO_PROCESS, tid)
    except (AttributeError, OSError) as exc:
        return {"asked": nice, "nice": None, "note": f"not set: {exc}"}
    if nice == before:
        return {"asked": nice, "nice": before, "before": before}
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except OSError as exc:
        why = ("lowering the nice value needs CAP_SYS_NICE (root)" if exc.errno in (errno.EPERM, errno.EACCES)
               else str(exc))
        return {"asked": nice, "nice": before, "before": before,
                "note": f"not set: {why}; the loop runs at nice {before}"}
    return {"asked": nice, "nice": os.getpriority(os.PRIO_PROCESS, tid), "before": before}


def restore_nice(record: dict) -> None:
    """Give the calling thread back the nice value `set_loop_nice` found (raising it is always allowed)."""
    if record.get("before") is not None and record.get("nice") != record["before"]:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), record["before"])
        except OSError:
            pass
