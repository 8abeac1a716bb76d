"""Preemption call conditioning (NTCIP 1202 preemptTable) and the preempt state values.

The call is the hard-wired input ORed with the call latched by a serial set request.
It must persist for the preempt delay before entry starts, and a call held longer
than the maximum presence (when set) is ignored until it drops and comes back.
The entry / dwell / exit sequence itself lives in :mod:`.controller`.
"""
from __future__ import annotations

from fmus.traffic_light.plan import PreemptConfig

NOT_ACTIVE, ENTRY, DWELL, EXIT = 0, 1, 2, 3
STATE_NAMES = {NOT_ACTIVE: "not active", ENTRY: "entry", DWELL: "dwell", EXIT: "exit"}
_EPS = 1e-9


class PreemptCall:
    def __init__(self, config: PreemptConfig):
        self.config = config
        self.input = False
        self.serial = False
        self.since: float | None = None  # time the call last became present

    @property
    def raw(self) -> bool:
        return self.input or self.serial

    def _set(self, attr: str, on: bool, now: float) -> bool:
        was = self.raw
        if getattr(self, attr) == on:
            return False
        setattr(self, attr, on)
        if self.raw and not was:
            self.since = now
        elif not self.raw:
            self.since = None
        return True

    def set_input(self, on: bool, now: float) -> bool:
        return self._set("input", on, now)

    def set_serial(self, on: bool, now: float) -> bool:
        return self._set("serial", on, now)

    def release(self, now: float) -> None:
        """Drop every source of the call (used by the change-bound projection)."""
        self.input = self.serial = False
        self.since = None

    def present(self, now: float) -> bool:
        if not self.raw or self.since is None:
            return False
        limit = self.config.max_presence
        return limit <= 0 or now < self.since + limit - _EPS

    def entry_due(self, now: float) -> bool:
        return self.present(now) and now >= self.since + self.config.delay - _EPS

    def event_times(self, now: float) -> list[float]:
        if self.since is None:
            return []
        out = [self.since + self.config.delay]
        if self.config.max_presence > 0:
            out.append(self.since + self.config.max_presence)
        return out
