"""A human driver at a signalised approach: holds its speed, stops for a red it can stop for.

Why a model and not the AV app: the vehicles around an application under
test (an emergency vehicle without a working OBU-to-planner path, cross
traffic at a preempted junction) are driven by people who look at the signal
head in front of them; they neither hear SPaT nor plan paths. What matters
for the signal applications is what such a driver does at the stop line:

* green (J2735 MovementPhaseState 5, 6): hold the desired speed (a
  proportional speed controller, bounded by `a_max` and `b_comfort`);
* yellow (7, 8), decided once when the yellow is first seen: stop when
  stopping at the line needs no more than `b_yellow` (the dilemma-zone rule
  of the ITE change-interval practice: a driver who can stop at a reasonable
  deceleration does), else go on through;
* red (3) or dark (1, a head that shows nothing is an all-way stop): stop
  when stopping needs no more than `b_max`; one that cannot goes through
  (and is counted as a red violation by the run's metrics);
* a stop is driven as people do: at speed until a stop at the line needs
  `b_comfort`, then at the deceleration that ends at the line (`stop_gap`
  short of it), then held until green.

Geometry: the approach is a straight lane; `travel_yaw` is its direction and
(`stop_x`, `stop_y`) any point on its stop line; positions are the vehicle's
rear axle, `front` metres behind its front bumper.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

GREEN = (5, 6)
YELLOW = (7, 8)
HOLD_DECEL = 1.0  # m/s^2 held while standing at the line (the brake pedal pressed)


@dataclass
class DriverParams:
    v_desired: float = 13.9   # m/s
    a_max: float = 2.0        # m/s^2, pulling away and speeding up
    b_comfort: float = 2.5    # m/s^2, where a planned stop begins
    b_yellow: float = 3.0     # m/s^2, the largest deceleration a driver stops at for a yellow
    b_max: float = 6.0        # m/s^2, the largest deceleration a driver stops at for a red
    k_speed: float = 1.0      # 1/s, speed controller gain
    stop_gap: float = 1.0     # m, where the front stops short of the stop line
    front: float = 3.7        # m, rear axle to front bumper
    stop_x: float = 0.0       # m, a point on the stop line
    stop_y: float = 0.0
    travel_yaw: float = 0.0   # rad, the lane's direction of travel

    def validate(self) -> None:
        """Raise ValueError naming every bad parameter."""
        problems = []
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                problems.append(f"{f.name} must be a finite number, got {value!r}")
        if not problems:
            for name in ("v_desired", "a_max", "b_comfort", "b_yellow", "b_max", "k_speed"):
                if getattr(self, name) <= 0:
                    problems.append(f"{name} must be > 0, got {getattr(self, name)!r}")
            for name in ("stop_gap", "front"):
                if getattr(self, name) < 0:
                    problems.append(f"{name} must be >= 0, got {getattr(self, name)!r}")
            if not self.b_comfort <= self.b_yellow <= self.b_max:
                problems.append(f"need b_comfort <= b_yellow <= b_max, got {self.b_comfort!r}, {self.b_yellow!r}, "
                                f"{self.b_max!r}")
        if problems:
            raise ValueError("; ".join(problems))


class SignalDriver:
    """The driver's decision at each step: `command(signal, x, y, v)` -> acceleration command (m/s^2)."""

    def __init__(self, params: DriverParams):
        params.validate()
        self.p = params
        self.decision: str | None = None  # "stop" / "go" for the current yellow or red, None on green
        self.holding = False               # stopping or standing for the signal
        self.braking = False               # the stop's braking has begun

    def distance_to_line(self, x: float, y: float) -> float:
        """Metres from the front bumper to the stop line along the lane (negative once over it)."""
        p = self.p
        along = (p.stop_x - x) * math.cos(p.travel_yaw) + (p.stop_y - y) * math.sin(p.travel_yaw)
        return along - p.front

    def cruise(self, v: float) -> float:
        p = self.p
        return max(-p.b_comfort, min(p.a_max, p.k_speed * (p.v_desired - v)))

    def command(self, signal: int, x: float, y: float, v: float) -> float:
        p = self.p
        d = self.distance_to_line(x, y) - p.stop_gap  # to where the front stops
        if signal in GREEN or d < -p.stop_gap:  # green, or over the line: the signal is behind it
            self.decision, self.holding, self.braking = None, False, False
            return self.cruise(v)
        need = v * v / (2.0 * max(d, 0.01))
        if self.decision is None:
            limit = p.b_yellow if signal in YELLOW else p.b_max
            self.decision = "stop" if need <= limit or v < 0.5 else "go"
        elif self.decision == "go" and signal not in YELLOW and need <= p.b_max:
            self.decision = "stop"  # went on for a yellow that turned red while it still can stop
        if self.decision == "go":
            self.holding = False
            return self.cruise(v)
        self.holding = True
        if v < 0.05 and (self.braking or d < 0.5):
            return -HOLD_DECEL  # standing at the line
        if self.braking or need >= p.b_comfort:
            self.braking = True  # once begun, the stop is braked through to the line (no on-off)
            return -min(max(need, 0.5), p.b_max)
        # not yet: roll on at speed (no faster than a stop from here at b_comfort allows)
        return min(self.cruise(v), max(-p.b_comfort, (math.sqrt(2.0 * p.b_comfort * d) - v) * p.k_speed))
