"""Is this BSM the ego? Recognising the RSU's surrogate BSM of the connected vehicle itself.

An RSU sends a surrogate BSM for every vehicle its camera tracks, the
connected vehicle too. Treated as an obstacle, that BSM sits 0.4-1.5 m from the
ego's own centre: a conflict at distance 0 and a full brake. An RSU's track is
a rough estimate of the vehicle, though: a fresh constant-velocity track
overshoots the speed (15.3 m/s for a vehicle at 8.3 m/s), its speed lags by
more than 2 m/s whenever the vehicle brakes, accelerates or turns, and its
heading can flip by ~180 degrees while the vehicle stands. So the rules are:

* ``surrogate``: a surrogate BSM (PSID 0x7F, an RSU's estimate) whose centre,
  predicted to the planning time, is within ``obu.self_gate_m`` of the ego's
  centre is the ego, with no speed or heading test: a centre that close means
  the footprints would overlap, which no other real vehicle can do;
* ``own_bsm``: a vehicle's own BSM (PSID 0x20) is the ego only as before:
  within ``self_gate_m``, heading within 30 degrees (any heading when both
  speeds are below 1 m/s) and speed within 2 m/s;
* ``hold`` (hysteresis, surrogate BSMs only): a temporary id of a station once
  recognised as the ego stays the ego while its centre is within
  ``self_hold_factor * self_gate_m`` and its heading within
  ``self_hold_heading_deg`` of the ego's (any heading when either speed is
  below ``self_hold_slow_speed``), or within it of any heading the ego had in
  the last ``self_hold_lag_s``: a constant-velocity track lags a turn, and
  just after the case study's right turn the cav's own track still pointed
  45 degrees behind it (taken for another vehicle, it made the cav brake
  hard for its own ghost). The first BSM of the id outside that gate
  forgets it, so a vehicle that later goes by under the same id is an obstacle
  again.

`EgoRecognizer.check` gives the rule that matched (or None); it is pure but for
the set of held ids, so tests drive it directly.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from av_app.config import ObuSection, VehicleSection
from av_app.fusion import predict_pose
from av_app.obu import V2xObject

SURROGATE, OWN_BSM, HOLD = "surrogate", "own_bsm", "hold"
RULES = (SURROGATE, OWN_BSM, HOLD)

# the test for a vehicle's own BSM (PSID 0x20), unchanged
OWN_HEADING_DEG = 30.0
OWN_SPEED_TOL = 2.0  # m/s
OWN_SLOW = 1.0  # m/s: both slower than this, any heading


@dataclass(frozen=True)
class SelfCheck:
    """One BSM against the ego at the planning time."""

    rule: str | None  # the rule that made it the ego (SURROGATE, OWN_BSM, HOLD) or None
    distance: float  # m between the BSM's predicted centre and the ego's centre
    heading_diff: float  # |yaw difference|, rad in [0, pi]

    @property
    def is_self(self) -> bool:
        return self.rule is not None


class EgoRecognizer:
    """Decides which BSMs describe the ego; remembers the surrogate ids recognised as the ego (hysteresis)."""

    def __init__(self, obu: ObuSection, vehicle: VehicleSection):
        self.gate = obu.self_gate_m
        self.hold_gate = obu.self_hold_factor * obu.self_gate_m
        self.hold_heading = math.radians(obu.self_hold_heading_deg)
        self.hold_slow = obu.self_hold_slow_speed
        self.hold_lag = obu.self_hold_lag_s
        self._yaws: deque[tuple[float, float]] = deque()  # (t, ego yaw) of the last hold_lag seconds
        self.centre_offset = vehicle.length / 2 - vehicle.rear_overhang  # rear axle -> centre
        self.held: set[tuple[str, str]] = set()  # (station, temporary id) recognised as the ego

    @staticmethod
    def key(obj: V2xObject) -> tuple[str, str]:
        return (obj.station, obj.id)

    def check(self, obj: V2xObject, state, t: float) -> SelfCheck:
        """`obj` against the ego `state` (rear-axle x, y, yaw, v) at time t; updates the held ids."""
        off = self.centre_offset
        cx, cy = state.x + off * math.cos(state.yaw), state.y + off * math.sin(state.yaw)
        x, y, yaw = predict_pose(obj.x, obj.y, obj.yaw, obj.speed, obj.yaw_rate, max(0.0, t - obj.t))
        d = math.hypot(x - cx, y - cy)
        dyaw = abs(math.atan2(math.sin(yaw - state.yaw), math.cos(yaw - state.yaw)))
        key = self.key(obj)
        self._remember(t, state.yaw)
        if obj.surrogate:
            if d < self.gate:
                self.held.add(key)
                return SelfCheck(SURROGATE, d, dyaw)
            slow = obj.speed < self.hold_slow or state.v < self.hold_slow
            if key in self.held and d < self.hold_gate and (self._recent_heading(yaw) < self.hold_heading or slow):
                return SelfCheck(HOLD, d, dyaw)
            self.held.discard(key)
            return SelfCheck(None, d, dyaw)
        heading_ok = dyaw < math.radians(OWN_HEADING_DEG) or obj.speed < OWN_SLOW and state.v < OWN_SLOW
        if d < self.gate and heading_ok and abs(obj.speed - state.v) < OWN_SPEED_TOL:
            return SelfCheck(OWN_BSM, d, dyaw)
        return SelfCheck(None, d, dyaw)

    def _remember(self, t: float, yaw: float) -> None:
        if not self._yaws or t > self._yaws[-1][0]:
            self._yaws.append((t, yaw))
        while self._yaws and self._yaws[0][0] < t - self.hold_lag:
            self._yaws.popleft()

    def _recent_heading(self, yaw: float) -> float:
        """The smallest |yaw difference| to a heading the ego had in the last hold_lag seconds, rad."""
        return min(abs(math.atan2(math.sin(yaw - y), math.cos(yaw - y))) for _, y in self._yaws)

    def forget(self, obj: V2xObject) -> None:
        """The object is gone (aged out): its id is no longer held."""
        self.held.discard(self.key(obj))


__all__ = ["EgoRecognizer", "SelfCheck", "RULES", "SURROGATE", "OWN_BSM", "HOLD"]
