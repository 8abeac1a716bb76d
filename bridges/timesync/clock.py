"""Clock arithmetic of the time protocol: NTP-style offset samples and the sim/wall mapping.

Offset: a participant sends ping at its t1, the master stamps receipt t2 and
reply t3 on its clock, the participant receives at t4. Then

    offset = ((t2 - t1) + (t3 - t4)) / 2      (master clock - participant clock)
    rtt    = (t4 - t1) - (t3 - t2)

The error of one sample is at most rtt/2 (all of the path asymmetry), so of
several exchanges the one with the smallest rtt is kept (NTP's clock filter).

Mapping: in realtime runs the master publishes (t_sim0, wall0_ns, rtf): at
master wall time wall0_ns the simulation was at t_sim0 and advances rtf
simulated seconds per wall second. The run clock this gives never runs
backwards: when the master's schedule moves back (a loop that slipped), the
mapping it publishes slews (`slewed`) instead of stepping, as NTP's adjtime
does, because receivers date-check signed messages against it (IEEE 1609.2's
time window and replay memory) and stages are stamped on it in order.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable


@dataclass(frozen=True)
class OffsetSample:
    offset_ns: int  # add to a local time to get master time
    rtt_ns: int


def offset_sample(t1: int, t2: int, t3: int, t4: int) -> OffsetSample:
    return OffsetSample(((t2 - t1) + (t3 - t4)) // 2, (t4 - t1) - (t3 - t2))


def best_sample(samples: Iterable[OffsetSample]) -> OffsetSample:
    """The minimum-RTT sample; ValueError when there is none."""
    samples = list(samples)
    if not samples:
        raise ValueError("no offset samples (no pong came back)")
    return min(samples, key=lambda s: s.rtt_ns)


@dataclass(frozen=True)
class TimeMapping:
    t_sim0: float
    wall0_ns: int
    rtf: float = 1.0

    def sim_time(self, master_ns: int) -> float:
        return self.t_sim0 + self.rtf * (master_ns - self.wall0_ns) / 1e9

    def master_ns(self, t_sim: float) -> int:
        return self.wall0_ns + round((t_sim - self.t_sim0) / self.rtf * 1e9)


SLEW_HORIZON_S = 0.2  # a run clock ahead of its schedule meets it again within this many wall seconds...
MIN_SLEW_RATE = 0.1  # ...unless that would take it below this share of its rate (it never stands still)


def slewed(current: TimeMapping | None, target: TimeMapping, now_ns: int, *,
           horizon_s: float = SLEW_HORIZON_S, min_rate: float = MIN_SLEW_RATE) -> TimeMapping:
    """The mapping to follow from `now_ns` when the schedule says `target`.

    `target` itself when it does not put the clock back (a step forward is
    only time that passed unseen); otherwise a mapping that continues from
    `current`'s time now at a lower rate, chosen to meet `target` within
    `horizon_s` but never below `min_rate` x its rate, so stamps keep
    increasing. Once the two meet, the caller switches to `target`.
    """
    if current is None:
        return target
    ahead = current.sim_time(now_ns) - target.sim_time(now_ns)
    if ahead <= 0.0:
        return target
    rate = max(min_rate * target.rtf, target.rtf - ahead / horizon_s)
    return TimeMapping(current.sim_time(now_ns), now_ns, rate)
