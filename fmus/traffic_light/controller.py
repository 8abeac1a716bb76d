"""NEMA dual-ring, barrier controller with NTCIP 1202 preemption, in continuous time.

The controller is event-driven: :meth:`Controller.advance` moves it to a time,
processing every interval change at its exact instant, so timings do not depend
on the communication step. Inputs (detector calls, the preemption call) are held
constant between calls, as FMI co-simulation delivers them.

Per ring, the interval is one of ``G`` (green of ``phase``), ``Y`` (yellow),
``R`` (red clearance) and ``W`` (no phase timing: waiting at the barrier, or
resting in red during preemption).

Normal operation
    * fixed time: a green lasts its split minus yellow and red clearance;
    * actuated (free): a green lasts at least its minimum green, is extended by
      each call for the passage time (gap-out) and ends at its maximum green
      (max-out). At a barrier both rings terminate together (simultaneous gap-out:
      a ready phase holds until the other ring's last phase is ready);
    * a ring that finishes its group waits (``W``) until the other ring has
      finished too; then both cross the barrier together.

Preemption (NTCIP 1202 preemptTable, ANCHORS T5), see :mod:`.preemption`:
    * entry: a running green is held until it has been green for
      min(phase min green, preempt min green), then its yellow and red clearance
      run, never shorter than the phase values; yellow and red already running
      finish; then the dwell phases turn green (no ring shows a phase across the
      barrier from them while they do);
    * dwell: while the call persists, and at least the dwell time;
    * exit: dwell phases that are not exit phases clear (phase yellow and red), the
      exit phases turn green and normal operation resumes from them (the local cycle
      restarts there: no offset-seeking transition).

Change bounds (J2735 minEndTime / maxEndTime): two forward projections of a copy
of the controller, one with no detector calls and the preemption call released
(earliest changes), one with calls on every detector and the preemption call held
as it is (latest changes). A change that does not happen in the projection horizon
is unknown (None). Neither projection foresees a new preemption call.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

from fmus.traffic_light.plan import GROUP_OF, PHASES, RING_OF, TimingPlan
from fmus.traffic_light.preemption import DWELL, ENTRY, EXIT, NOT_ACTIVE, PreemptCall

EPS = 1e-9
INF = math.inf
G, Y, R, W = "G", "Y", "R", "W"

# J2735 MovementPhaseState
DARK, STOP_AND_REMAIN = 1, 3
PERMISSIVE_GREEN, PROTECTED_GREEN = 5, 6
PERMISSIVE_CLEARANCE, PROTECTED_CLEARANCE = 7, 8

# AB3418 ring interval codes (PATH GetLongStatus8 "interval" nibbles)
IV_MIN_GREEN, IV_PASSAGE, IV_RED_REST, IV_PREEMPT = 0x02, 0x05, 0x08, 0x09
IV_MAX_TERM, IV_GAP_TERM, IV_FORCE_OFF, IV_RED_CLEAR = 0x0C, 0x0D, 0x0E, 0x0F


@dataclass
class Ring:
    index: int
    groups: tuple[tuple[int, ...], tuple[int, ...]]  # used phases per barrier group
    interval: str = W
    phase: int = 0
    group: int = 0
    t_start: float = 0.0       # start of the interval
    t_end: float = INF         # end of Y and R
    green_start: float = 0.0
    hold_end: float | None = None  # preemption entry: the green ends here
    target: int = 0            # preemption: phase to serve after clearing (0 = rest in red)
    routed: bool = False       # preemption: this ring follows `target`, not the plan
    done: bool = True          # W: finished its group
    termination: int = IV_FORCE_OFF  # why the last green ended (interval code of its yellow)


class Controller:
    """Dual-ring controller state; see the module docstring."""

    def __init__(self, plan: TimingPlan, t0: float = 0.0):
        plan.validate()
        self.plan = plan
        self.pre = plan.preempt
        self.rings = [Ring(r, plan.ring_groups(r)) for r in (0, 1)]
        self.calls = {p: False for p in PHASES}
        self.last_call = {p: -INF for p in PHASES}
        self.call = PreemptCall(self.pre)
        self.pstate = NOT_ACTIVE
        self.t_dwell = 0.0
        self.group = 0
        self.version = 0               # bumped on every change: keys the change-bound cache
        self.local_zero_passed = False
        self.cycle_starts = 0
        self._bounds: tuple | None = None
        if plan.actuated:
            self.now = t0
            self.cycle_origin = t0
            self._begin_group(0, t0)
        else:
            # start the plan at the local zero before t0 and run it up to t0
            zero = t0 - math.fmod(t0 - plan.offset, plan.cycle) % plan.cycle
            self.now = zero
            self.cycle_origin = zero
            self._begin_group(0, zero)
            self.advance(t0)
        self.local_zero_passed = False

    # -- inputs ---------------------------------------------------------------------
    def set_inputs(self, calls: dict[int, bool] | None = None, preempt: bool | None = None) -> None:
        """Detector calls per phase and the hard-wired preemption call, from `now` on."""
        if calls is not None:
            for p in PHASES:
                on = bool(calls.get(p, False))
                if on != self.calls[p]:
                    if not on:
                        self.last_call[p] = self.now  # the call was present up to now
                    self.calls[p] = on
                    self.version += 1
        if preempt is not None and self.call.set_input(bool(preempt), self.now):
            self.version += 1

    def set_serial_preempt(self, on: bool) -> None:
        """The preemption call latched by a serial set request (ORed with the input)."""
        if self.call.set_serial(bool(on), self.now):
            self.version += 1

    # -- time -------------------------------------------------------------------------
    def advance(self, t_end: float) -> None:
        """Run to `t_end`, every change at its instant."""
        while True:
            self._settle()
            te = self._next_event_time()
            if te > t_end + EPS:
                break
            self.now = max(self.now, te)
        self.now = max(self.now, t_end)
        self._settle()

    def _settle(self) -> None:
        for _ in range(200):
            changed = self._preempt_update()
            for ring in self.rings:
                changed |= self._ring_update(ring)
            changed |= self._barrier_update()
            if not changed:
                return
            self.version += 1
        raise RuntimeError(f"traffic-light controller did not settle at t = {self.now}")  # a bug, not input

    def _next_event_time(self) -> float:
        now, t = self.now, INF
        for ring in self.rings:
            if ring.interval == G:
                te = self._green_ready_time(ring)
            elif ring.interval in (Y, R):
                te = ring.t_end
            else:
                continue
            if now + EPS < te < t:
                t = te
        for te in self.call.event_times(now):
            if now + EPS < te < t:
                t = te
        if self.pstate == DWELL:
            te = self.t_dwell + self.pre.dwell
            if now + EPS < te < t:
                t = te
        return t

    # -- rings ------------------------------------------------------------------------
    def _green_ready_time(self, ring: Ring) -> float:
        """When the current green may end (barrier partner aside)."""
        p = ring.phase
        if ring.hold_end is not None:
            return ring.hold_end
        if ring.routed:  # dwelling (or waiting to exit) on a preemption phase
            return INF
        t = self.plan.phases[p]
        if not self.plan.actuated:
            return ring.green_start + self.plan.green_time(p)
        if self.calls[p]:
            gap = INF  # a call present keeps extending the green
        elif self.last_call[p] >= ring.green_start - EPS:
            gap = self.last_call[p] + t.passage
        else:
            gap = -INF  # no actuation during this green: it gaps out at min green
        return min(max(ring.green_start + t.min_green, gap), ring.green_start + t.max_green)

    def _ready(self, ring: Ring) -> bool:
        return ring.interval == G and self.now >= self._green_ready_time(ring) - EPS

    def _may_terminate(self, ring: Ring) -> bool:
        """Simultaneous gap-out: in actuated mode a group's last phase waits for the other ring's."""
        if ring.routed or not self.plan.actuated:
            return True
        phases = ring.groups[ring.group]
        if ring.phase != phases[-1]:
            return True
        other = self.rings[1 - ring.index]
        other_phases = other.groups[ring.group]
        if not other_phases or other.routed:
            return True
        if other.interval == W:
            return other.done
        if other.phase != other_phases[-1]:
            return False
        return other.interval != G or self._ready(other)

    def _ring_update(self, ring: Ring) -> bool:
        now = self.now
        if ring.interval == G:
            ready_t = self._green_ready_time(ring)
            if now >= ready_t - EPS and self._may_terminate(ring):
                ts = ready_t if ready_t >= now - EPS else now
                ring.termination = self._termination_code(ring, ready_t)
                self._start_clearance(ring, ts)
                return True
        elif ring.interval == Y:
            if now >= ring.t_end - EPS:
                ts = ring.t_end
                ring.interval, ring.t_start = R, ts
                ring.t_end = ts + self._red_time(ring)
                return True
        elif ring.interval == R:
            if now >= ring.t_end - EPS:
                self._after_clearance(ring, ring.t_end)
                return True
        return False

    def _termination_code(self, ring: Ring, ready_t: float) -> int:
        if ring.routed or ring.hold_end is not None or not self.plan.actuated:
            return IV_FORCE_OFF
        return IV_MAX_TERM if ready_t >= ring.green_start + self.plan.phases[ring.phase].max_green - EPS else IV_GAP_TERM

    def _entry_clearance(self, ring: Ring) -> bool:
        return self.pstate == ENTRY and ring.routed

    def _yellow_time(self, ring: Ring) -> float:
        y = self.plan.phases[ring.phase].yellow
        return max(y, self.pre.enter_yellow) if self._entry_clearance(ring) else y

    def _red_time(self, ring: Ring) -> float:
        r = self.plan.phases[ring.phase].red_clear
        return max(r, self.pre.enter_red) if self._entry_clearance(ring) else r

    def _start_clearance(self, ring: Ring, ts: float) -> None:
        ring.interval, ring.t_start, ring.hold_end = Y, ts, None
        ring.t_end = ts + self._yellow_time(ring)

    def _start_green(self, ring: Ring, phase: int, ts: float) -> None:
        ring.interval, ring.phase, ring.group = G, phase, GROUP_OF[phase]
        ring.t_start = ring.green_start = ts
        ring.t_end, ring.hold_end, ring.done = INF, None, False

    def _rest(self, ring: Ring, ts: float, done: bool = True) -> None:
        ring.interval, ring.phase, ring.t_start, ring.t_end, ring.done = W, 0, ts, INF, done

    def _after_clearance(self, ring: Ring, ts: float) -> None:
        if ring.routed:
            self._rest(ring, ts, done=False)  # preemption routes it from W
            return
        phases = ring.groups[ring.group]
        i = phases.index(ring.phase) if ring.phase in phases else len(phases) - 1
        if i + 1 < len(phases):
            self._start_green(ring, phases[i + 1], ts)
        else:
            self._rest(ring, ts, done=True)

    def _begin_group(self, group: int, ts: float) -> None:
        if not any(r.groups[group] for r in self.rings):
            group = 1 - group
        self.group = group
        for ring in self.rings:
            ring.group = group
            if ring.groups[group]:
                self._start_green(ring, ring.groups[group][0], ts)
            else:
                self._rest(ring, ts, done=True)
                ring.group = group
        if group == 0 or not any(r.groups[0] for r in self.rings):
            self.cycle_starts += 1
            self.local_zero_passed = True
            if self.plan.actuated:
                self.cycle_origin = ts

    def _barrier_update(self) -> bool:
        if self.pstate != NOT_ACTIVE:
            return False
        if all(r.interval == W and r.done for r in self.rings):
            self._begin_group(1 - self.group, self.now)
            return True
        return False

    # -- preemption -------------------------------------------------------------------------
    def _barrier_safe(self, ring: Ring, phase: int) -> bool:
        """No other ring shows a phase across the barrier from `phase`."""
        for other in self.rings:
            if other is not ring and other.interval in (G, Y, R) and GROUP_OF[other.phase] != GROUP_OF[phase]:
                return False
        return True

    def _preempt_update(self) -> bool:
        if not self.pre.enabled:
            return False
        now, changed = self.now, False
        if self.pstate in (NOT_ACTIVE, EXIT) and self.call.entry_due(now):
            self._enter()
            changed = True
        if self.pstate in (ENTRY, EXIT):
            for ring in self.rings:
                if ring.routed and ring.interval == W and ring.target and self._barrier_safe(ring, ring.target):
                    self._start_green(ring, ring.target, now)
                    changed = True
            if all(self._at_target(r) for r in self.rings):
                if self.pstate == ENTRY:
                    self.pstate, self.t_dwell = DWELL, now
                else:
                    self._resume(now)
                changed = True
        if self.pstate == DWELL and not self.call.present(now) and now >= self.t_dwell + self.pre.dwell - EPS:
            self._exit()
            changed = True
        return changed

    def _at_target(self, ring: Ring) -> bool:
        if ring.target:
            return ring.interval == G and ring.phase == ring.target
        return ring.interval == W

    def _enter(self) -> None:
        self.pstate = ENTRY
        now = self.now
        for ring, dwell in zip(self.rings, self.pre.dwell_phases):
            ring.routed, ring.target = True, dwell
            if ring.interval == G:
                if ring.phase == dwell:
                    ring.hold_end = None  # already serving its dwell phase
                else:
                    served = min(self.plan.phases[ring.phase].min_green, self.pre.min_green)
                    ring.hold_end = max(now, ring.green_start + served)
            elif ring.interval == W:
                ring.done = False

    def _exit(self) -> None:
        self.pstate = EXIT
        now = self.now
        for ring, target in zip(self.rings, self.pre.exit_phases):
            ring.routed, ring.target = True, target
            if ring.interval == G and ring.phase != target:
                ring.hold_end = now  # the dwell phase clears now (phase yellow and red)
            elif ring.interval == G:
                ring.green_start = ring.t_start = now  # the exit phase continues as a fresh green

    def _resume(self, now: float) -> None:
        """Back to the plan from the exit phases."""
        self.pstate = NOT_ACTIVE
        exit_group = next(GROUP_OF[p] for p in self.pre.exit_phases if p)
        self.group = exit_group
        for ring in self.rings:
            ring.routed, ring.target, ring.hold_end = False, 0, None
            ring.group = exit_group
            if ring.interval == W:
                ring.done = True
        if not self.plan.actuated:
            first = next(p for p in self.pre.exit_phases if p)
            self.cycle_origin = now - self.plan.green_start_in_cycle(first)

    # -- outputs --------------------------------------------------------------------------------
    def display(self, phase: int) -> str:
        """'G', 'Y', 'R' or 'dark' (unused phase)."""
        if not self.plan.used(phase):
            return "dark"
        ring = self.rings[RING_OF[phase]]
        if ring.phase == phase and ring.interval in (G, Y):
            return ring.interval
        return R

    def movement_state(self, phase: int) -> int:
        """J2735 MovementPhaseState of the phase's signal group."""
        d = self.display(phase)
        permissive = bool(self.plan.permissive >> (phase - 1) & 1)
        if d == "dark":
            return DARK
        if d == G:
            return PERMISSIVE_GREEN if permissive else PROTECTED_GREEN
        if d == Y:
            return PERMISSIVE_CLEARANCE if permissive else PROTECTED_CLEARANCE
        return STOP_AND_REMAIN

    def ring_phase(self, ring: int) -> int:
        """The phase timing in a ring (green, yellow or red clearance); 0 when none."""
        return self.rings[ring].phase

    def interval_code(self, ring: int) -> int:
        r = self.rings[ring]
        if r.interval == G:
            if r.routed and self.pstate in (DWELL, ENTRY) and r.phase == r.target:
                return IV_PREEMPT
            if self.now < r.green_start + self.plan.phases[r.phase].min_green - EPS:
                return IV_MIN_GREEN
            return IV_PASSAGE
        if r.interval == Y:
            return r.termination
        if r.interval == R:
            return IV_RED_CLEAR
        return IV_PREEMPT if self.pstate != NOT_ACTIVE else IV_RED_REST

    def cycle_time(self) -> float:
        """Local cycle clock: time since local zero (fixed time) or the last cycle start (actuated)."""
        if self.plan.actuated:
            return self.now - self.cycle_origin
        return math.fmod(self.now - self.cycle_origin, self.plan.cycle) % self.plan.cycle

    def change_bounds(self) -> tuple[dict[int, float | None], dict[int, float | None]]:
        """(earliest, latest) simulated time at which each phase's display next changes; None unknown."""
        # Bounds are absolute times: they change only with the state, except while a call
        # is present (its release "now" moves with time).
        moving = self.call.raw or (self.plan.actuated and any(self.calls.values()))
        key = (self.version, self.now if moving else None)
        if self._bounds is None or self._bounds[0] != key:
            lo = self._project(calls=False)
            hi = self._project(calls=True)
            mins = {p: (min(lo[p], hi[p]) if lo[p] is not None and hi[p] is not None else lo[p]) for p in PHASES}
            maxs = {p: (max(lo[p], hi[p]) if lo[p] is not None and hi[p] is not None else None) for p in PHASES}
            self._bounds = (key, mins, maxs)
        return self._bounds[1], self._bounds[2]

    def _project(self, calls: bool) -> dict[int, float | None]:
        sim = copy.copy(self)
        sim.rings = [copy.copy(r) for r in self.rings]
        sim.calls, sim.last_call = dict(self.calls), dict(self.last_call)
        sim.call = copy.copy(self.call)
        sim._bounds = None
        sim.set_inputs({p: calls for p in PHASES}, preempt=None)
        if not calls:
            sim.call.release(sim.now)
        used = [p for p in PHASES if self.plan.used(p)]
        before = {p: sim.display(p) for p in used}
        found: dict[int, float | None] = {p: None for p in PHASES}
        horizon = self.now + 3.0 * (self.plan.cycle_bound() + self.pre.delay + self.pre.dwell
                                    + 2 * max(t.yellow + t.red_clear for t in self.plan.phases.values())) + 1.0
        pending = set(used)
        while pending:
            te = sim._next_event_time()
            if te > horizon:
                break
            sim.now = te
            sim._settle()
            for p in list(pending):
                if sim.display(p) != before[p]:
                    found[p] = te
                    pending.discard(p)
        return found
