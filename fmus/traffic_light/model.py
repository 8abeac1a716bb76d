"""The traffic-light controller with its RS-232 port: the plain-Python model behind the FMU.

:class:`TrafficLightModel` couples the dual-ring controller (:mod:`.controller`),
the two directions of the serial line (:mod:`.uart`) and the AB3418-like endpoint
(:mod:`.protocol`) on one time line: within a step, every received byte and every
answer is handled at its own instant, with the controller advanced to that instant.

Bytes handed in at a communication point t start on the receive line at t; an
answer to a request that arrived at t_r starts at t_r + turnaround (or when the
transmit line is free) and each of its bytes leaves after its character time.
A step returns the bytes whose stop bit was sent by the end of the step, and
:attr:`TrafficLightModel.tx_end_time` is when the last of them was.
"""
from __future__ import annotations

from fmus.traffic_light.controller import EPS, Controller
from fmus.traffic_light.plan import PHASES, TimingPlan
from fmus.traffic_light.preemption import NOT_ACTIVE
from fmus.traffic_light.protocol import ControllerEndpoint, ab3418
from fmus.traffic_light.uart import UartConfig, Wire


class TrafficLightModel:
    def __init__(self, plan: TimingPlan, uart: UartConfig | None = None, station: int = 1,
                 turnaround: float = 0.010, max_pending: int = 1, fcs_order: str = ab3418.LSB_FIRST,
                 max_frame: int = ab3418.MAX_FRAME, rx_buffer: int = 65536, t0: float = 0.0):
        uart = uart or UartConfig()
        uart.validate()
        if not 0 <= station <= 62:
            raise ValueError(f"station = {station!r}: must be 0..62 (AB3418 address (station << 2) + 1)")
        if not 0 <= turnaround <= 10.0:
            raise ValueError(f"turnaround = {turnaround!r}: must be 0..10 s")
        if max_pending < 1:
            raise ValueError(f"max_pending_requests = {max_pending!r}: must be >= 1")
        if rx_buffer < 1:
            raise ValueError(f"rx_buffer_size = {rx_buffer!r}: must be >= 1 byte")
        if not ab3418.MIN_BODY <= max_frame <= 65535:
            raise ValueError(f"max_frame = {max_frame!r}: must be {ab3418.MIN_BODY}..65535 bytes")
        self.plan = plan
        self.uart = uart
        self.controller = Controller(plan, t0)
        self.rx = Wire(uart, capacity=rx_buffer)
        self.tx = Wire(uart)
        self.endpoint = ControllerEndpoint(station, self._status_data, self.controller.set_serial_preempt,
                                           lambda: self.tx.free_at, turnaround=turnaround,
                                           max_pending=max_pending, fcs_order=fcs_order, max_frame=max_frame)
        self.now = t0
        self.rx_bytes = 0
        self.rx_end_time = -1.0
        self.tx_bytes = 0
        self.tx_end_time = -1.0
        self.seq_number = 0

    @property
    def counters(self) -> dict[str, int]:
        return self.endpoint.counters

    # -- stepping -----------------------------------------------------------------------
    def step(self, t: float, dt: float, calls: dict[int, bool] | None = None, preempt: bool = False,
             rx: bytes = b"") -> bytes:
        """One communication step [t, t + dt]; returns the bytes sent on the transmit line in it."""
        if t < self.now - 1e-6:
            raise ValueError(f"time went backwards: step at t = {t} after the model reached {self.now}")
        self._run_until(t)
        self.controller.set_inputs(calls or {}, preempt)
        if rx:
            accepted = self.rx.send(rx, t)
            self.counters["err_rx_overflow"] += len(rx) - accepted
        t_end = t + dt
        self._run_until(t_end)
        sent = self.tx.pop_until(t_end)
        if sent:
            self.tx_bytes += len(sent)
            self.tx_end_time = sent[-1][0]
        return bytes(b for _, b in sent)

    def _run_until(self, t_end: float) -> None:
        ctl, rx, ep = self.controller, self.rx, self.endpoint
        while True:
            t_rx, t_ans = rx.next_time(), ep.next_answer_time()
            ts = min(t_rx, t_ans)
            if ts > t_end + EPS:
                break
            ctl.advance(ts)
            if t_rx <= t_ans:
                done, b = rx.pop()
                self.rx_bytes += 1
                self.rx_end_time = done
                ep.on_byte(b, done)
            else:
                self.tx.send(ep.pop_answer(ts), ts)
                ep.answer_sent(self.tx.free_at)
        ctl.advance(t_end)
        self.now = max(self.now, t_end)

    @property
    def idle(self) -> bool:
        """Nothing on either line and no answer waiting: the link has finished everything it was given."""
        return not len(self.rx) and not len(self.tx) and not self.endpoint.busy

    # -- status -------------------------------------------------------------------------
    def _bitmap(self, display: str) -> int:
        ctl = self.controller
        return sum(1 << (p - 1) for p in PHASES if ctl.display(p) == display)

    def _status_data(self, request: int) -> bytes:
        ctl = self.controller
        status = ab3418.STATUS_PREEMPT if ctl.pstate != NOT_ACTIVE else 0
        if ctl.local_zero_passed:
            status |= ab3418.STATUS_LOCAL_ZERO
            ctl.local_zero_passed = False
        pattern = 255 if self.plan.actuated else 1  # 255 = free; plan 1
        greens = self._bitmap("G")
        if request == ab3418.GET_SHORT_STATUS:
            return ab3418.ShortStatus(greens, status, pattern).encode()
        calls = sum(1 << (p - 1) for p in PHASES if ctl.calls[p])
        active = sum(1 << (ring.phase - 1) for ring in ctl.rings if ring.phase)
        mins, maxs = ctl.change_bounds()
        ttc = []
        for ring in ctl.rings:
            p = ring.phase
            lo = mins[p] if p else None
            hi = maxs[p] if p else None
            ttc += [ab3418.tenths(None if lo is None else lo - ctl.now),
                    ab3418.tenths(None if hi is None else hi - ctl.now)]
        cycle_time = ctl.cycle_time()
        master = ctl.now % self.plan.cycle if not self.plan.actuated else cycle_time
        self.seq_number = (self.seq_number + 1) & 0xFF
        return ab3418.LongStatus8(
            status=status, pattern=pattern,
            preemption=0x01 if (ctl.call.present(ctl.now) or ctl.pstate != NOT_ACTIVE) else 0,
            phase_calls=calls, active_phases=active,
            interval=ctl.interval_code(0) | ctl.interval_code(1) << 4,
            presence=(calls, 0, 0, 0), master_clock=int(master) & 0xFF, local_clock=int(cycle_time) & 0xFF,
            seq_number=self.seq_number, greens=greens, yellows=self._bitmap("Y"), preempt_state=ctl.pstate,
            phase_a=ctl.rings[0].phase, phase_b=ctl.rings[1].phase,
            ttc_a_min=ttc[0], ttc_a_max=ttc[1], ttc_b_min=ttc[2], ttc_b_max=ttc[3],
            cycle_time=ab3418.tenths(cycle_time),
        ).encode()
