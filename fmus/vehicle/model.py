"""Plain-Python vehicle dynamics behind the VehicleDynamics FMU.

Kinematic single-track ("KS", bicycle) model of the CommonRoad vehicle models
(M. Althoff, M. Koschi, G. Würsching, "CommonRoad: Vehicle Models", TU München,
section "Kinematic Single-Track Model"), extended by a longitudinal road load
(aerodynamic drag and rolling resistance) so that coasting and cruising cost
acceleration as they do on a real road.

State (reference point: centre of the rear axle, as in the CommonRoad KS model):
    x, y   position in the world frame [m]
    yaw    heading, counter-clockwise from the x axis [rad]; kept continuous
           (not wrapped to +-pi) so that co-simulation outputs never jump
    v      speed along the heading [m/s], negative when reversing
    steer  actual front-wheel angle [rad]

Inputs, held constant over one ``step`` (zero-order hold, as FMI co-simulation
delivers them): ``accel_cmd`` [m/s^2], ``steer_cmd`` [rad] and ``reverse``.

Only the standard library is used so that the FMU needs no binary dependency.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields

__all__ = ["VehicleParams", "VehicleModel"]


@dataclass(frozen=True)
class VehicleParams:
    """Model parameters; defaults are CommonRoad vehicle 1 (Ford Escort).

    Frozen: the model validates them once, at construction, not every step.

    Sources: CommonRoad vehicle models, ``parameters_vehicle1`` (mass 84 lb s^2/ft,
    a = 2.9 ft, b = 4.95 ft, steering and longitudinal constraints).
    The road-load values (cd_a, c_rr, rho_air) are typical passenger-car values,
    not CommonRoad data (the KS model has no road load).
    """

    wheelbase: float = 2.3927      # m, CommonRoad vehicle 1: a 0.8839 + b 1.5088
    mass: float = 1225.9           # kg, CommonRoad vehicle 1
    a_max: float = 11.5            # m/s², max longitudinal acceleration (CommonRoad vehicle 1)
    a_min: float = -11.5           # m/s², braking limit (negative)
    v_switch: float = 4.755        # m/s, above it acceleration is power-limited: a_lim = a_max * v_switch / v
    v_max: float = 45.8            # m/s, CommonRoad vehicle 1
    v_min: float = -13.9           # m/s (reverse), CommonRoad vehicle 1
    steer_max: float = 0.910       # rad, steering angle limit (symmetric)
    steer_rate_max: float = 0.4    # rad/s, steering-rate limit (symmetric)
    cd_a: float = 0.66             # m², drag coefficient × frontal area
    c_rr: float = 0.012            # rolling-resistance coefficient
    rho_air: float = 1.2           # kg/m³
    g: float = 9.81                # m/s²
    dt_internal: float = 0.001     # s, largest internal integration sub-step

    def validate(self) -> None:
        """Raise ValueError naming the first nonsensical field.

        Checked up front so that a bad FMU parameter fails at initialisation
        with a clear message instead of producing NaN trajectories later.
        """
        for f in fields(self):
            val = getattr(self, f.name)
            if isinstance(val, bool) or not isinstance(val, numbers.Real):
                raise ValueError(f"VehicleParams.{f.name} must be a real number, got {val!r}")
            if not math.isfinite(val):
                raise ValueError(f"VehicleParams.{f.name} must be finite, got {val!r}")
        positive = ("wheelbase", "mass", "dt_internal", "a_max", "v_switch",
                    "steer_max", "steer_rate_max", "v_max")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"VehicleParams.{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("cd_a", "c_rr", "rho_air", "g"):
            if getattr(self, name) < 0:
                raise ValueError(f"VehicleParams.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.a_min >= 0:
            raise ValueError(f"VehicleParams.a_min must be < 0 (a braking limit), got {self.a_min!r}")
        if self.v_min > 0:
            raise ValueError(f"VehicleParams.v_min must be <= 0 (reverse speed limit), got {self.v_min!r}")
        if self.steer_max >= math.pi / 2:
            # tan(steer) in the yaw equation is singular at pi/2.
            raise ValueError(f"VehicleParams.steer_max must be < pi/2, got {self.steer_max!r}")


def _finite(name: str, value) -> float:
    """Convert an input to float, rejecting NaN/inf/non-numbers with its name."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value


def _rk4_scalar(fu, u: float, tau: float) -> float:
    """One classical RK4 step of the (autonomous, decoupled) speed equation.

    Same arithmetic as the speed component of ``VehicleModel._rk4``; used to
    locate the instant at which the speed reaches an event threshold.
    """
    h2 = 0.5 * tau
    k1 = fu(u)
    k2 = fu(u + h2 * k1)
    k3 = fu(u + h2 * k2)
    k4 = fu(u + tau * k3)
    return u + tau / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _event_time(fu, u0: float, b: float, tau: float, u_tau: float) -> float:
    """Time in (0, tau] at which the RK4 speed from u0 reaches b.

    u0 and u_tau lie on opposite sides of b.  Newton's method on the RK4 step
    length (derivative ~ fu), safeguarded by bisection of the bracket.
    """
    t_lo, t_hi = 0.0, tau
    below = u0 < b  # side of b where the bracket's lower end lies
    t = tau * (b - u0) / (u_tau - u0)
    tol = 1e-14 * max(1.0, abs(b))
    for _ in range(60):
        g = _rk4_scalar(fu, u0, t) - b
        if abs(g) <= tol:
            break
        if (g < 0) == below:
            t_lo = t
        else:
            t_hi = t
        if t_hi - t_lo <= 1e-16 * tau:
            break
        d = fu(g + b)
        t_new = t - g / d if d != 0.0 else -1.0
        if not t_lo < t_new < t_hi:
            t_new = 0.5 * (t_lo + t_hi)
        t = t_new
    return min(max(t, 0.0), tau)


class VehicleModel:
    """Kinematic single-track vehicle with road load, gear logic and actuator limits.

    Internally the speed is handled in the "gear frame" u = s*v with s = +1 in
    forward and s = -1 in reverse gear, so that forward driving and reversing
    share one code path: u >= 0 is motion in the gear's direction, traction
    pushes u up, brakes and road load oppose the motion.
    """

    def __init__(self, params: VehicleParams | None = None, x0=0.0, y0=0.0, yaw0=0.0, v0=0.0, steer0=0.0):
        self.params = params if params is not None else VehicleParams()
        self.params.validate()
        p = self.params
        self.x = _finite("x0", x0)
        self.y = _finite("y0", y0)
        self.yaw = _finite("yaw0", yaw0)
        self.v = _finite("v0", v0)
        self.steer = _finite("steer0", steer0)
        if not p.v_min <= self.v <= p.v_max:
            raise ValueError(f"v0 must lie in [v_min, v_max] = [{p.v_min}, {p.v_max}], got {v0!r}")
        if abs(self.steer) > p.steer_max:
            raise ValueError(f"steer0 must lie in [-steer_max, steer_max] = ±{p.steer_max}, got {steer0!r}")
        self.a = 0.0
        self.yaw_rate = 0.0
        self.update_outputs(0.0, self.steer)

    # ------------------------------------------------------------------ limits
    def accel_limit(self, v: float) -> float:
        """Upper (traction) acceleration limit at speed v.

        CommonRoad vehicle models, "Acceleration constraints": a_max up to
        v_switch, above it a_max*v_switch/v (constant engine power, the
        acceleration falls with speed).  |v| so that reversing is limited too.
        """
        p = self.params
        w = abs(v)
        return p.a_max if w <= p.v_switch else p.a_max * p.v_switch / w

    def road_load(self, v: float) -> float:
        """Deceleration magnitude (>= 0) from drag and rolling resistance.

        Standard road-load formula: F = 0.5*rho*cd_a*v^2 + c_rr*m*g, divided by m.
        Rolling resistance only acts while the wheels roll (v != 0); at rest it
        becomes a holding force, handled in ``net_accel``.
        """
        p = self.params
        if v == 0.0:
            return 0.0
        return 0.5 * p.rho_air * p.cd_a * v * v / p.mass + p.c_rr * p.g

    # --------------------------------------------------------- gear-frame core
    def _drag_k(self) -> float:
        p = self.params
        return 0.5 * p.rho_air * p.cd_a / p.mass

    def _u_cap(self, s: float) -> float:
        """Largest speed in the gear's direction: v_max forward, -v_min reverse."""
        return self.params.v_max if s > 0 else -self.params.v_min

    def _raw_rate(self, u: float, c: float) -> float:
        """du/dt for u != 0 (gear frame, c = gear-frame command), before the cap."""
        p = self.params
        sigma = 1.0 if u > 0 else -1.0
        w = abs(u)
        if c > 0:
            act = min(c, self.accel_limit(w))  # traction always pushes in gear direction
        else:
            act = sigma * max(c, p.a_min)     # brakes oppose the motion
        return act - sigma * (self._drag_k() * w * w + p.c_rr * p.g)

    def _gear_rate(self, u: float, c: float, u_cap: float) -> float:
        """True du/dt including standstill holding and the speed cap."""
        p = self.params
        if u == 0.0:
            # At rest, brakes and rolling resistance are holding (static) forces:
            # they can keep the car still but never push it backwards.
            val = max(0.0, min(c, p.a_max) - p.c_rr * p.g) if c > 0 else 0.0
        else:
            val = self._raw_rate(u, c)
        if u >= u_cap and val > 0.0:
            val = 0.0
        return val

    def net_accel(self, v: float, accel_cmd: float, reverse: bool = False) -> float:
        """Net longitudinal acceleration dv/dt at speed v for the given command.

        accel_cmd (traction > 0 / brake < 0 in forward gear; mirrored in reverse
        gear) is clipped to [a_min, accel_limit(v)] (CommonRoad acceleration
        constraints); road load opposes the motion; at v == 0 rolling resistance
        and brakes only hold the car; speed is capped at v_max / v_min.
        """
        s = -1.0 if reverse else 1.0
        return s * self._gear_rate(s * float(v), s * float(accel_cmd), self._u_cap(s)) + 0.0

    def _regime(self, u: float, c: float, u_cap: float):
        """Smooth piece of the speed dynamics valid from u in the direction of motion.

        Returns (fu, lo, hi): fu is the smooth right-hand side (None while the
        speed is held constant) valid while lo <= u <= hi.  The break points are
        standstill (0), the speed cap and the speed |u| = u_k where the clipped
        command meets the power limit (a kink that would spoil RK4's order).
        """
        p = self.params
        f_true = self._gear_rate(u, c, u_cap)
        if f_true == 0.0:
            return None, u, u  # held: standstill, at the cap, or in equilibrium
        breaks = {0.0, u_cap}
        if c > 0:
            u_k = p.v_switch * p.a_max / min(c, p.a_max)
            breaks.update((u_k, -u_k))
        breaks = sorted(breaks)
        lo, hi = -math.inf, math.inf
        for b in breaks:
            if b < u or (b == u and f_true > 0):
                lo = b
            elif hi == math.inf:
                hi = b
        # Representative point of the interval fixes which formula applies.
        if lo == -math.inf:
            m = hi - 1.0
        elif hi == math.inf:
            m = lo + 1.0
        else:
            m = 0.5 * (lo + hi)
        sigma = 1.0 if m > 0 else -1.0
        k = self._drag_k()
        crr_g = p.c_rr * p.g
        if c > 0 and abs(m) > p.v_switch * p.a_max / min(c, p.a_max):
            pw = p.a_max * p.v_switch  # power-limited traction a_max*v_switch/|u|

            def fu(uu, sigma=sigma, k=k, crr_g=crr_g, pw=pw):
                return pw / max(sigma * uu, 1e-9) - sigma * (k * uu * uu + crr_g)
        else:
            act = min(c, p.a_max) if c > 0 else sigma * max(c, p.a_min)

            def fu(uu, sigma=sigma, k=k, crr_g=crr_g, act=act):
                return act - sigma * (k * uu * uu + crr_g)
        return fu, lo, hi

    # ------------------------------------------------------------ integration
    def _rk4(self, u: float, tau: float, st0: float, w: float, fu, s: float):
        """One RK4 step of (x, y, yaw, u); steer(t) = st0 + w*t is exact.

        CommonRoad KS model: x' = v cos(yaw), y' = v sin(yaw),
        yaw' = v tan(steer) / l, v' = net acceleration.
        """
        inv_l = 1.0 / self.params.wheelbase
        h2 = 0.5 * tau
        tan0 = math.tan(st0)
        tan_m = math.tan(st0 + h2 * w)
        tan1 = math.tan(st0 + tau * w)
        yaw = self.yaw
        fz = fu if fu is not None else (lambda _u: 0.0)

        v1 = s * u
        k1u = fz(u)
        k1x, k1y, k1p = v1 * math.cos(yaw), v1 * math.sin(yaw), v1 * tan0 * inv_l
        u2 = u + h2 * k1u
        v2, yaw2 = s * u2, yaw + h2 * k1p
        k2u = fz(u2)
        k2x, k2y, k2p = v2 * math.cos(yaw2), v2 * math.sin(yaw2), v2 * tan_m * inv_l
        u3 = u + h2 * k2u
        v3, yaw3 = s * u3, yaw + h2 * k2p
        k3u = fz(u3)
        k3x, k3y, k3p = v3 * math.cos(yaw3), v3 * math.sin(yaw3), v3 * tan_m * inv_l
        u4 = u + tau * k3u
        v4, yaw4 = s * u4, yaw + tau * k3p
        k4u = fz(u4)
        k4x, k4y, k4p = v4 * math.cos(yaw4), v4 * math.sin(yaw4), v4 * tan1 * inv_l
        t6 = tau / 6.0
        return (self.x + t6 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
                self.y + t6 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y),
                yaw + t6 * (k1p + 2.0 * k2p + 2.0 * k3p + k4p),
                u + t6 * (k1u + 2.0 * k2u + 2.0 * k3u + k4u))

    def _segment(self, T: float, st0: float, w: float, c: float, s: float, u_cap: float) -> None:
        """Advance by T with steer(t) = st0 + w*t, splitting at speed events.

        The speed equation is autonomous and scalar, so within one smooth
        regime the speed is monotone; when an RK4 step leaves the regime's
        interval the crossing instant is located and the step is split there,
        and the speed is set exactly onto the threshold (e.g. exactly 0 on a stop).
        """
        t = 0.0
        for _ in range(32):  # at most a handful of events per segment
            rem = T - t
            if rem <= 0.0:
                return
            u = s * self.v
            fu, lo, hi = self._regime(u, c, u_cap)
            st = st0 + w * t
            if fu is None:
                if u != 0.0:  # constant nonzero speed: still moves and turns
                    self.x, self.y, self.yaw, _ = self._rk4(u, rem, st, w, None, s)
                return
            nx, ny, nyaw, nu = self._rk4(u, rem, st, w, fu, s)
            if lo <= nu <= hi:
                self.x, self.y, self.yaw, self.v = nx, ny, nyaw, s * nu + 0.0
                return
            b = hi if nu > hi else lo
            outward = fu(b) > 0 if b == hi else fu(b) < 0
            if not outward:
                # RK4 overshoot next to an equilibrium the exact solution never
                # crosses: keep the step, clamp the speed inside the interval.
                self.x, self.y, self.yaw, self.v = nx, ny, nyaw, s * b + 0.0
                return
            tau = _event_time(fu, u, b, rem, nu)
            self.x, self.y, self.yaw, _ = self._rk4(u, tau, st, w, fu, s)
            self.v = s * b + 0.0  # + 0.0 turns -0.0 into 0.0
            t += tau
        # Safety net, not expected to be reached: finish without event handling
        # but keep the speed inside the current regime's interval.
        if T - t > 0.0:
            u = s * self.v
            fu, lo, hi = self._regime(u, c, u_cap)
            self.x, self.y, self.yaw, nu = self._rk4(u, T - t, st0 + w * t, w, fu, s)
            if fu is not None:
                self.v = s * min(max(nu, lo), hi)

    def _substep(self, h: float, c: float, target: float, s: float, u_cap: float) -> None:
        """Advance by h, splitting where the rate-limited steering reaches its target."""
        rate = self.params.steer_rate_max
        rem = h
        while rem > 0.0:
            delta = target - self.steer
            if delta == 0.0:
                self._segment(rem, self.steer, 0.0, c, s, u_cap)
                return
            w = rate if delta > 0 else -rate
            t_settle = abs(delta) / rate
            if t_settle <= rem:
                self._segment(t_settle, self.steer, w, c, s, u_cap)
                self.steer = target  # exactly on target: no overshoot
                rem -= t_settle
            else:
                self._segment(rem, self.steer, w, c, s, u_cap)
                self.steer += w * rem
                return

    # -------------------------------------------------------------- interface
    def update_outputs(self, accel_cmd: float, steer_cmd: float, reverse: bool = False) -> None:
        """Recompute a and yaw_rate for the current state and inputs (no time advance).

        Needed at FMU initialisation, where outputs must be consistent with the
        start values before the first step.
        """
        accel_cmd = _finite("accel_cmd", accel_cmd)
        _finite("steer_cmd", steer_cmd)
        self.a = self.net_accel(self.v, accel_cmd, bool(reverse))
        # CommonRoad KS model: yaw rate = v tan(steer) / l.
        self.yaw_rate = self.v * math.tan(self.steer) / self.params.wheelbase

    def step(self, dt: float, accel_cmd: float, steer_cmd: float, reverse: bool = False) -> None:
        """Advance the state by dt with inputs held constant.

        dt may be any size; it is cut into equal sub-steps no longer than
        params.dt_internal, each integrated with RK4 and split exactly where the
        steering settles or the speed reaches standstill, the cap or the
        power-limit kink, so that the result hardly depends on how the caller
        splits time.
        """
        dt = _finite("dt", dt)
        if dt < 0:
            raise ValueError(f"dt must be >= 0, got {dt!r}")
        accel_cmd = _finite("accel_cmd", accel_cmd)
        steer_cmd = _finite("steer_cmd", steer_cmd)
        p = self.params
        reverse = bool(reverse)
        if dt > 0.0:
            s = -1.0 if reverse else 1.0
            c = s * accel_cmd
            u_cap = self._u_cap(s)
            target = min(max(steer_cmd, -p.steer_max), p.steer_max)
            n = max(1, math.ceil(dt / p.dt_internal - 1e-9))
            h = dt / n
            for _ in range(n):
                self._substep(h, c, target, s, u_cap)
        self.update_outputs(accel_cmd, steer_cmd, reverse)
