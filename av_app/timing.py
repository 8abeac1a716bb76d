"""Stage 3 in simulated time: when does each piece of the AV app's work count as done?

The run's latency policy (apps_contract.md) decides, per stage:

* ``fixed`` (lockstep, bit-for-bit reproducible): the stage takes the seconds
  the scenario gives in `[participants.NAME] latencies` (keys `verify`,
  `decode`, `fuse`, `plan`, `can_command`, `perception`), or, for a key the
  scenario leaves out, the app's `[latency]` config value;
* ``measured`` (lockstep): the stage takes the real compute time it took;
* ``realtime``: stages are stamped with the simulation time read off the
  master's clock when they finish.

A stage's output time is its input's time plus its charge: a V2X frame that
arrived at t_a is verified at t_a + verify, decoded at + decode and in the
fused object list at + fuse; only from then on can a plan use it. A lidar scan
of time t_s gives obstacles at t_s + perception.
"""
from __future__ import annotations

from typing import Callable

from av_app.config import LatencySection

STAGE_KEYS = ("verify", "decode", "fuse", "plan", "can_command", "perception")
POLICIES = ("fixed", "measured", "realtime")


class StageClock:
    def __init__(self, policy: str, latencies: dict | None, defaults: LatencySection,
                 now: Callable[[], float] | None = None):
        if policy not in POLICIES:
            raise ValueError(f"latency policy {policy!r}: expected one of {', '.join(POLICIES)}")
        if policy == "realtime" and now is None:
            raise ValueError("the realtime policy needs the simulation clock (now)")
        self.policy, self.now = policy, now
        self.fixed = {k: float(getattr(defaults, k)) for k in STAGE_KEYS}
        self.from_scenario = sorted(k for k in (latencies or {}) if k in STAGE_KEYS)
        for k in self.from_scenario:
            self.fixed[k] = float(latencies[k])

    def charge(self, stage: str, start: float, wall_s: float) -> float:
        """The simulation time at which `stage`, begun at `start`, counts as done."""
        if self.policy == "fixed":
            return start + self.fixed[stage]
        if self.policy == "measured":
            return start + max(0.0, wall_s)
        return max(start, self.now())

    def describe(self) -> dict:
        out = {"policy": self.policy}
        if self.policy == "fixed":
            out["latencies_s"] = dict(self.fixed)
            out["from_scenario"] = list(self.from_scenario)
        return out
