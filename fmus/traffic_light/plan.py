"""Signal timing plans of a NEMA dual-ring, eight-phase controller, with NTCIP 1202 range checks.

Ring 1 serves phases 1-4, ring 2 phases 5-8; the barrier splits both rings into
group A (phases 1, 2 | 5, 6) and group B (3, 4 | 7, 8). Within a group a ring
serves its phases in number order (lead-lead). A phase is used when its split is
positive; a plain 4-approach, 2-phase intersection uses phases 2, 6 (one street)
and 4, 8 (the other).

Fixed-time plans follow NTCIP 1202 coordination: the split of a phase includes its
yellow change and red clearance, the splits of each ring add up to the cycle, and
both rings reach each barrier together (equal split sums per group). The local
cycle starts (local zero) at the start of the first green of group A; the offset
is the master time of local zero, modulo the cycle.

Errors name the FMU parameter (``yellow_3``, ``split_4``, ...). Ranges are those of
the NTCIP 1202 objects (phaseYellowChange 3.0-25.5 s in tenths, ANCHORS T4, ...);
the MUTCD guidance of ANCHORS T1 (yellow 3-6 s, red clearance <= 6 s) is reported by
:meth:`TimingPlan.mutcd_warnings`, not enforced.

The ITE helpers compute yellow change (ANCHORS T2) and all-red (T3) intervals.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

PHASES = tuple(range(1, 9))
RING_OF = {p: 0 if p <= 4 else 1 for p in PHASES}
GROUP_OF = {p: 0 if p in (1, 2, 5, 6) else 1 for p in PHASES}
# phases of (ring, group) in service order
RING_GROUPS = (((1, 2), (3, 4)), ((5, 6), (7, 8)))
MPH = 0.44704  # m/s per mile per hour
FT = 0.3048    # m per foot


class PlanError(ValueError):
    """An invalid timing parameter; the message starts with the FMU parameter name."""


@dataclass(frozen=True)
class PhaseTiming:
    split: float = 0.0       # s, 0 = phase not used; includes yellow and red clearance
    min_green: float = 5.0   # s, phaseMinimumGreen
    yellow: float = 3.0      # s, phaseYellowChange
    red_clear: float = 2.0   # s, phaseRedClear
    max_green: float = 40.0  # s, phaseMaximum1 (actuated mode)
    passage: float = 2.0     # s, phasePassage (actuated mode: vehicle extension)


@dataclass(frozen=True)
class PreemptConfig:
    """One preemption input (NTCIP 1202 preemptTable row)."""

    enabled: bool = True
    delay: float = 0.0           # s, preemptDelay: the call must persist this long before entry
    min_green: float = 5.0       # s, preemptMinimumGreen: entry holds a running green at most min(phase min green, this)
    dwell: float = 10.0          # s, preemptDwellGreen: shortest dwell
    max_presence: float = 0.0    # s, preemptMaximumPresence: a call held longer is ignored (0 = no limit)
    enter_yellow: float = 0.0    # s, preemptEnterYellowChange (0 = phase yellow; never shorter than it)
    enter_red: float = 0.0       # s, preemptEnterRedClear (0 = phase red clearance; never shorter than it)
    dwell_phases: tuple[int, int] = (2, 6)  # per ring, 0 = the ring rests in red
    exit_phases: tuple[int, int] = (4, 8)   # per ring, 0 = the ring joins at the next barrier


@dataclass(frozen=True)
class TimingPlan:
    phases: dict[int, PhaseTiming] = field(default_factory=dict)
    cycle: float = 130.0
    offset: float = 0.0
    actuated: bool = False  # False: fixed time (greens from splits); True: free, actuated (gap-out / max-out)
    permissive: int = 0     # bit k-1: phase k reports permissive (J2735 5/7) instead of protected (6/8)
    preempt: PreemptConfig = field(default_factory=PreemptConfig)

    # -- structure ---------------------------------------------------------------------
    def used(self, phase: int) -> bool:
        return self.phases[phase].split > 0

    def ring_groups(self, ring: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """Used phases of `ring` per barrier group, in service order."""
        return tuple(tuple(p for p in group if self.used(p)) for group in RING_GROUPS[ring])

    def green_time(self, phase: int) -> float:
        """Fixed-time green of a phase: split minus yellow and red clearance."""
        t = self.phases[phase]
        return t.split - t.yellow - t.red_clear

    def green_start_in_cycle(self, phase: int) -> float:
        """Local cycle time at which a phase's green starts in undisturbed fixed-time operation."""
        ring, group = RING_OF[phase], GROUP_OF[phase]
        start = 0.0
        for g in range(group + 1):
            for p in RING_GROUPS[ring][g]:
                if g == group and p == phase:
                    return start
                start += self.phases[p].split
            if g < group:  # a ring reaches the barrier when the longer ring does
                start = max(start, self._group_length(0))
        return start

    def _group_length(self, group: int) -> float:
        return max(sum(self.phases[p].split for p in RING_GROUPS[r][group]) for r in (0, 1))

    def cycle_bound(self) -> float:
        """Longest time one cycle can take (fixed: the cycle; actuated: max greens)."""
        if not self.actuated:
            return self.cycle
        total = 0.0
        for g in (0, 1):
            total += max(sum(self.phases[p].max_green + self.phases[p].yellow + self.phases[p].red_clear
                             for p in RING_GROUPS[r][g] if self.used(p)) for r in (0, 1))
        return total

    # -- checks ----------------------------------------------------------------------
    def validate(self) -> None:
        """Raise PlanError naming the first parameter out of its NTCIP 1202 range or inconsistent."""
        if set(self.phases) != set(PHASES):
            raise PlanError(f"phases: expected timings for phases 1-8, got {sorted(self.phases)}")
        if not any(self.used(p) for p in PHASES):
            raise PlanError("split_1..split_8: no phase is used (every split is 0)")
        for p in PHASES:
            t = self.phases[p]
            _range(f"split_{p}", t.split, 0.0, 255.0)                    # splitTime 0..255 s
            _range(f"yellow_{p}", t.yellow, 3.0, 25.5, tenths=True)      # phaseYellowChange 30..255 (T4)
            _range(f"red_clear_{p}", t.red_clear, 0.0, 25.5, tenths=True)  # phaseRedClear 0..255
            _range(f"min_green_{p}", t.min_green, 1.0, 255.0)            # phaseMinimumGreen 1..255 s
            _range(f"max_green_{p}", t.max_green, 1.0, 255.0)            # phaseMaximum1 1..255 s
            _range(f"passage_{p}", t.passage, 0.0, 25.5, tenths=True)    # phasePassage 0..255 tenths
            if not self.used(p):
                continue
            if self.actuated:
                if t.max_green < t.min_green:
                    raise PlanError(f"max_green_{p} = {t.max_green:g} s: must be >= min_green_{p} ({t.min_green:g} s)")
            elif self.green_time(p) < t.min_green - 1e-9:
                raise PlanError(f"split_{p} = {t.split:g} s: shorter than min_green_{p} + yellow_{p} + red_clear_{p} "
                                f"= {t.min_green + t.yellow + t.red_clear:g} s")
        if not self.actuated:
            _range("cycle", self.cycle, 1.0, 255.0)      # patternCycleTime (0 = free: use actuated)
            _range("offset", self.offset, 0.0, 255.0)
            if self.offset >= self.cycle:
                raise PlanError(f"offset = {self.offset:g} s: must be < cycle ({self.cycle:g} s)")
            for g, names in ((0, "1+2 / 5+6"), (1, "3+4 / 7+8")):
                sums = [sum(self.phases[p].split for p in RING_GROUPS[r][g]) for r in (0, 1)]
                if all(s > 0 for s in sums) and abs(sums[0] - sums[1]) > 1e-6:
                    raise PlanError(f"split_{RING_GROUPS[0][g][0]}: the splits of phases {names} must reach the "
                                    f"barrier together: ring 1 has {sums[0]:g} s, ring 2 {sums[1]:g} s")
            for r in (0, 1):
                total = sum(self.phases[p].split for g in (0, 1) for p in RING_GROUPS[r][g])
                if total > 0 and abs(total - self.cycle) > 1e-6:
                    first = RING_GROUPS[r][0][0]
                    raise PlanError(f"cycle = {self.cycle:g} s: the splits of ring {r + 1} "
                                    f"(split_{first}..split_{first + 3}) add up to {total:g} s")
        if not 0 <= self.permissive <= 0xFF:
            raise PlanError(f"permissive_phases = {self.permissive}: a bit mask of phases 1-8 (0..255)")
        self._validate_preempt()

    def _validate_preempt(self) -> None:
        c = self.preempt
        _range("preempt_delay", c.delay, 0.0, 600.0)          # preemptDelay 0..600 s
        _range("preempt_min_green", c.min_green, 0.0, 255.0)  # preemptMinimumGreen 0..255 s
        _range("preempt_dwell", c.dwell, 1.0, 255.0)          # preemptDwellGreen 1..255 s
        _range("preempt_max_presence", c.max_presence, 0.0, 65535.0)
        for name, v in (("preempt_enter_yellow", c.enter_yellow), ("preempt_enter_red", c.enter_red)):
            _range(name, v, 0.0, 25.5, tenths=True)
        if not c.enabled:
            return
        for kind, phases in (("dwell", c.dwell_phases), ("exit", c.exit_phases)):
            for ring, p in enumerate(phases):
                name = f"preempt_{kind}_phase_r{ring + 1}"
                if p == 0:
                    continue
                if p not in PHASES or RING_OF[p] != ring:
                    raise PlanError(f"{name} = {p}: must be a ring {ring + 1} phase "
                                    f"({', '.join(str(q) for q in PHASES if RING_OF[q] == ring)}) or 0")
                if not self.used(p):
                    raise PlanError(f"{name} = {p}: phase {p} is not used (split_{p} = 0)")
            used = [p for p in phases if p]
            if len(used) == 2 and GROUP_OF[used[0]] != GROUP_OF[used[1]]:
                raise PlanError(f"preempt_{kind}_phase_r2 = {phases[1]}: phases {used[0]} and {used[1]} are on "
                                "opposite sides of the barrier and cannot be green together")
        if not any(c.exit_phases):
            raise PlanError("preempt_exit_phase_r1: preemption needs an exit phase on at least one ring "
                            "(or set preempt_enabled = false)")

    def mutcd_warnings(self) -> list[str]:
        """MUTCD guidance (ANCHORS T1) the used phases do not meet: yellow 3-6 s, red clearance <= 6 s."""
        out = []
        for p in PHASES:
            if not self.used(p):
                continue
            t = self.phases[p]
            if not 3.0 <= t.yellow <= 6.0:
                out.append(f"yellow_{p} = {t.yellow:g} s is outside the MUTCD 3-6 s guidance")
            if t.red_clear > 6.0:
                out.append(f"red_clear_{p} = {t.red_clear:g} s exceeds the MUTCD 6 s guidance")
        return out


def _range(name: str, value: float, lo: float, hi: float, tenths: bool = False) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise PlanError(f"{name} = {value!r}: must be a finite number")
    if not lo - 1e-9 <= value <= hi + 1e-9:
        unit = " (NTCIP 1202 tenths of a second)" if tenths else ""
        raise PlanError(f"{name} = {value:g} s: out of range {lo:g}..{hi:g} s{unit}")
    if tenths and abs(value * 10.0 - round(value * 10.0)) > 1e-6:
        raise PlanError(f"{name} = {value:g} s: NTCIP 1202 sets it in tenths of a second")


# -- ITE change and clearance intervals ------------------------------------------------------
def ite_yellow(speed: float, reaction_time: float = 1.0, decel: float = 3.05, grade: float = 0.0,
               g: float = 9.81) -> float:
    """ITE yellow change interval Y = t + v / (2a + 2Gg), SI units (speed in m/s, grade as a fraction)."""
    if speed <= 0:
        raise ValueError(f"approach speed must be > 0, got {speed!r}")
    return reaction_time + speed / (2.0 * decel + 2.0 * grade * g)


def ite_yellow_us(speed_mph: float, reaction_time: float = 1.0, decel_ftps2: float = 10.0,
                  grade: float = 0.0) -> float:
    """The ITE formula as ITE prints it: Y = t + 1.47 V / (2a + 64.4 G), V in mph, a in ft/s2 (ANCHORS T2).

    1.47 ft/s per mph rounds 22/15 = 1.4667, so this form is 0.23 % longer than :func:`ite_yellow`
    for the same speed; ANCHORS T2 (3.57 s at 35 mph, 4.31 s at 45 mph) are values of this form.
    """
    if speed_mph <= 0:
        raise ValueError(f"approach speed must be > 0, got {speed_mph!r}")
    return reaction_time + 1.47 * speed_mph / (2.0 * decel_ftps2 + 64.4 * grade)


def ite_all_red(width: float, speed: float, vehicle_length: float = 20 * FT) -> float:
    """ITE red clearance R = (W + L) / v, SI units (W: stop line to far side of the conflict, m)."""
    if speed <= 0:
        raise ValueError(f"approach speed must be > 0, got {speed!r}")
    return (width + vehicle_length) / speed


def ite_all_red_us(width_ft: float, speed_mph: float, length_ft: float = 20.0) -> float:
    """ITE red clearance as ITE prints it: R = (W + L) / (1.47 V), feet and mph (ANCHORS T3)."""
    if speed_mph <= 0:
        raise ValueError(f"approach speed must be > 0, got {speed_mph!r}")
    return (width_ft + length_ft) / (1.47 * speed_mph)


def _ceil_tenth(x: float) -> float:
    return math.ceil(round(x * 10.0, 6)) / 10.0


def design_yellow(speed: float, **kwargs) -> float:
    """ITE yellow rounded up to the NTCIP tenth and kept within MUTCD's 3-6 s (ANCHORS T1, T2)."""
    return min(6.0, max(3.0, _ceil_tenth(ite_yellow(speed, **kwargs))))


def design_all_red(width: float, speed: float, vehicle_length: float = 20 * FT) -> float:
    """ITE all-red rounded up to the NTCIP tenth, at most MUTCD's 6 s (ANCHORS T1, T3)."""
    return min(6.0, _ceil_tenth(ite_all_red(width, speed, vehicle_length)))
