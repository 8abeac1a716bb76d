"""SPaT from what the controller reports over AB3418, and the MAP beside it.

A status answer tells, per phase (= signal group), green and yellow (bit k-1 =
phase k), the active phase of each ring with its earliest and latest time to
change (tenths of a second), and the preemption state. The answer describes
the controller when it *started sending*: `t_status = t_rx - wire_bytes * 10 /
baud` (8N1), so the SPaT's time marks and its age include the serial link's
own timing, as they would on a box.

Movement states: green -> protected-Movement-Allowed, yellow ->
protected-clearance, otherwise stop-And-Remain; a flashing controller ->
stop-Then-Proceed. Time marks (J2735 TimeMark: seconds within the UTC hour,
0.1 s): for the active phase of a ring, minEnd/maxEnd = t_status + its time to
change; other groups carry none. Intersection status bits: preemptIsActive,
fixedTimeOperation (a plan) or trafficDependentOperation (free), failureFlash.

No stale SPaT: nothing is sent while the newest status is older than
`spat.max_age_s` (a lost controller stops the SPaT instead of repeating its last
state).
"""
from __future__ import annotations

import time
from collections import deque

from bridges import ab3418
from bridges.j2735.spat import IntersectionSignals, Movement, Spat
from bridges.security import PSID_SPAT_MAP
from bridges.v2x import tx_key, unix_time
from rsu_app.bsm_stage import Transmission, minute_of_year, sign_encoded
from rsu_app.intersection_map import map_message

GREEN, YELLOW, RED, FLASH = ("protected-Movement-Allowed", "protected-clearance", "stop-And-Remain",
                             "stop-Then-Proceed")
# IntersectionStatusObject bits (J2735)
FAILURE_FLASH, PREEMPT_ACTIVE, FIXED_TIME, TRAFFIC_DEPENDENT = 2, 3, 5, 6
BITS_PER_CHAR = 10  # 8N1: start + 8 data + stop (ANCHORS S1)


def _status_bits(*bits: int) -> tuple[bytes, int]:
    value = 0
    for b in bits:
        value |= 0x8000 >> b
    return value.to_bytes(2, "big"), 16


class SpatStage:
    def __init__(self, station: str, epoch_unix_s: float, envelope, latency, *, intersection_id: int,
                 signal_groups: list[int], baud: int, max_age_s: float):
        self.key = tx_key(station)
        self.epoch, self.envelope, self.latency = float(epoch_unix_s), envelope, latency
        self.intersection_id, self.signal_groups = intersection_id, list(signal_groups)
        self.baud, self.max_age_s = baud, max_age_s
        self.status: ab3418.LongStatus8 | ab3418.ShortStatus | None = None
        self.t_status: float | None = None
        self.t_rx: float | None = None
        self.statuses = 0
        self.sent = 0
        self.suppressed_stale = 0
        self.revision = 0
        self._last_states: tuple | None = None
        self.encode_s: deque[float] = deque(maxlen=20000)
        self.history: deque[tuple[float, float, tuple]] = deque(maxlen=4)  # (t_rx, t_status, states), for logs

    def on_status(self, status, wire_bytes: int, t_rx: float) -> None:
        self.status, self.t_rx = status, t_rx
        self.t_status = t_rx - wire_bytes * BITS_PER_CHAR / self.baud
        self.statuses += 1

    def movements(self) -> tuple[list[Movement], tuple[bytes, int]]:
        st = self.status
        long = isinstance(st, ab3418.LongStatus8)
        flash = bool(st.status & ab3418.STATUS_FLASH)
        bits = []
        if flash:
            bits.append(FAILURE_FLASH)
        if st.status & ab3418.STATUS_PREEMPT:
            bits.append(PREEMPT_ACTIVE)
        bits.append(TRAFFIC_DEPENDENT if st.pattern == 255 else FIXED_TIME)
        out = []
        for g in self.signal_groups:
            bit = 1 << (g - 1) if 1 <= g <= 8 else 0
            if flash:
                state = FLASH
            elif st.greens & bit:
                state = GREEN
            elif long and st.yellows & bit:
                state = YELLOW
            else:
                state = RED
            lo = hi = None
            if long and g in (st.phase_a, st.phase_b):
                tmin, tmax = (st.ttc_a_min, st.ttc_a_max) if g == st.phase_a else (st.ttc_b_min, st.ttc_b_max)
                lo, hi = (None if v == ab3418.UNKNOWN_TENTHS else self._time_mark(v / 10.0) for v in (tmin, tmax))
            out.append(Movement(g, state, min_end_s=lo, max_end_s=hi))
        return out, _status_bits(*bits)

    def _time_mark(self, seconds_from_status: float) -> float:
        """A moment as J2735 TimeMark seconds within the UTC hour (0.1 s resolution, 0..3599.9)."""
        unix = unix_time(self.t_status + seconds_from_status, self.epoch)
        return round(unix % 3600.0, 1) % 3600.0

    def send(self, t: float) -> Transmission | None:
        """The SPaT of slot t, from the newest status received by t; None when there is none fresh enough."""
        if self.status is None:
            return None
        if t - self.t_status > self.max_age_s:
            self.suppressed_stale += 1
            return None
        c0 = time.perf_counter()
        movements, status_bits = self.movements()
        states = tuple((m.signal_group, m.state) for m in movements)
        if states != self._last_states:
            if self._last_states is not None:
                self.revision = (self.revision + 1) % 128
            self._last_states = states
        unix = unix_time(t, self.epoch)
        moy = minute_of_year(unix)
        spat = Spat([IntersectionSignals(self.intersection_id, revision=self.revision, moy=moy,
                                         time_stamp_ms=int(unix * 1000 + 1e-6) % 60000, status=status_bits,
                                         movements=movements)], moy=moy)
        signed = sign_encoded(spat.encode(), c0, t, PSID_SPAT_MAP, self.envelope, self.latency, self.epoch)
        self.sent += 1
        self.encode_s.append(signed.encode_s)
        self.history.append((self.t_rx, self.t_status, states))
        return Transmission(self.key, signed.frame, signed.t_sign, signed.marks(), "spat",
                            compute_s=signed.compute_s())


class MapStage:
    """The MAP at its rate: the geometry is fixed for the run, the time stamp follows the slot."""

    def __init__(self, station: str, epoch_unix_s: float, envelope, latency, geometry, revision: int):
        self.key = tx_key(station)
        self.epoch, self.envelope, self.latency = float(epoch_unix_s), envelope, latency
        self.geometry, self.revision = geometry, revision
        self.sent = 0

    def send(self, t: float) -> Transmission:
        c0 = time.perf_counter()
        unix = unix_time(t, self.epoch)
        payload = map_message(self.geometry, self.revision, minute_of_year(unix)).encode()
        signed = sign_encoded(payload, c0, t, PSID_SPAT_MAP, self.envelope, self.latency, self.epoch)
        self.sent += 1
        return Transmission(self.key, signed.frame, signed.t_sign, signed.marks(), "map",
                            compute_s=signed.compute_s())
