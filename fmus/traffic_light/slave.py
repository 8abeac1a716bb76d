"""TrafficLightController FMU: a NEMA dual-ring controller with preemption and an RS-232 port.

Plan representation: one scalar parameter per phase and quantity (``split_1`` ..
``split_8``, ``yellow_k``, ``red_clear_k``, ``min_green_k``, ``max_green_k``,
``passage_k``). FMI 2 has no arrays, and scalars keep what a String-encoded plan
would lose: a unit on every value, per-key type checks and "did you mean" in
scenario files, `v2i info` listing, and range errors that name the exact
parameter (NTCIP 1202 ranges, checked at initialisation).

Serial port: the bytes exchanged with the outside are hex strings (FMI 2 has no
binary type). ``serial_rx_hex`` holds the bytes that reach the controller's
receive pin at this communication point; it is consumed by the next step (and
reads back empty after it). ``serial_tx_hex`` holds the bytes the controller sent
during the last step; ``serial_tx_end_time`` is when the last of them left the
line. Both directions are timed by the UART model (baud, data bits, parity, stop
bits), answers start ``turnaround`` after their request (AB3418 T2).

Outputs per signal group k (= phase k): ``state_k`` (J2735 MovementPhaseState:
1 dark, 3 red, 5/6 green, 7/8 yellow), ``min_end_k`` / ``max_end_k`` (simulated
time of the earliest / latest next change, -1 when unknown).
"""
from __future__ import annotations

from pythonfmu.enums import Fmi2Status

from fmus.slave_base import V2iSlave, Var
from fmus.traffic_light.model import TrafficLightModel
from fmus.traffic_light.plan import PHASES, PhaseTiming, PlanError, PreemptConfig, TimingPlan
from fmus.traffic_light.protocol import COUNTERS, ab3418
from fmus.traffic_light.uart import UartConfig

# Defaults: the SUMO NEMA example (ANCHORS T6): cycle 130 s, yellow 3 s, red 2 s, min green 5 s,
# extension (passage) 2 s; splits 20 s for the left turns (odd phases), 45 s for the throughs.
_SPLIT = {p: 20.0 if p % 2 else 45.0 for p in PHASES}
_MAX_GREEN = {p: 15.0 if p % 2 else 40.0 for p in PHASES}
_P = PreemptConfig()

_PLAN = tuple(
    var
    for p in PHASES
    for var in (
        Var(f"split_{p}", "parameter", f"Split of phase {p}: green + yellow + red clearance (0 = phase not used)", "s", _SPLIT[p]),
        Var(f"min_green_{p}", "parameter", f"Minimum green of phase {p} (NTCIP phaseMinimumGreen, 1-255 s)", "s", 5.0),
        Var(f"yellow_{p}", "parameter", f"Yellow change of phase {p} (NTCIP phaseYellowChange, 3.0-25.5 s in tenths)", "s", 3.0),
        Var(f"red_clear_{p}", "parameter", f"Red clearance of phase {p} (NTCIP phaseRedClear, 0-25.5 s in tenths)", "s", 2.0),
        Var(f"max_green_{p}", "parameter", f"Maximum green of phase {p}, actuated mode (NTCIP phaseMaximum1)", "s", _MAX_GREEN[p]),
        Var(f"passage_{p}", "parameter", f"Passage (vehicle extension) of phase {p}, actuated mode (0-25.5 s)", "s", 2.0),
    )
) + (
    Var("cycle", "parameter", "Cycle length of the fixed-time plan; each ring's splits add up to it", "s", 130.0),
    Var("offset", "parameter", "Master time of local zero (start of the group-A greens), modulo the cycle", "s", 0.0),
    Var("actuated", "parameter", "False: fixed time; true: free, actuated by the call_k inputs (gap-out, max-out)",
        start=False, type="Boolean"),
    Var("permissive_phases", "parameter", "Bit k-1 set: signal group k reports permissive green/clearance (J2735 5/7)",
        start=0, type="Integer"),
)
_PREEMPT = (
    Var("preempt_enabled", "parameter", "Whether the preemption call is served", start=True, type="Boolean"),
    Var("preempt_delay", "parameter", "NTCIP preemptDelay: the call must persist this long before entry", "s", _P.delay),
    Var("preempt_min_green", "parameter", "NTCIP preemptMinimumGreen: entry holds a running green min(phase min green, this)", "s", _P.min_green),
    Var("preempt_dwell", "parameter", "NTCIP preemptDwellGreen: shortest dwell on the dwell phases", "s", _P.dwell),
    Var("preempt_max_presence", "parameter", "NTCIP preemptMaximumPresence: a longer call is ignored (0 = no limit)", "s", _P.max_presence),
    Var("preempt_enter_yellow", "parameter", "NTCIP preemptEnterYellowChange; 0 or shorter than the phase's = phase yellow", "s", _P.enter_yellow),
    Var("preempt_enter_red", "parameter", "NTCIP preemptEnterRedClear; 0 or shorter than the phase's = phase red clearance", "s", _P.enter_red),
    Var("preempt_dwell_phase_r1", "parameter", "Ring-1 phase green during dwell (0 = ring 1 rests in red)", start=_P.dwell_phases[0], type="Integer"),
    Var("preempt_dwell_phase_r2", "parameter", "Ring-2 phase green during dwell (0 = ring 2 rests in red)", start=_P.dwell_phases[1], type="Integer"),
    Var("preempt_exit_phase_r1", "parameter", "Ring-1 phase served after preemption (0 = none)", start=_P.exit_phases[0], type="Integer"),
    Var("preempt_exit_phase_r2", "parameter", "Ring-2 phase served after preemption (0 = none)", start=_P.exit_phases[1], type="Integer"),
)
_SERIAL = (
    Var("station", "parameter", "AB3418 station number; address byte (station << 2) + 1", start=1, type="Integer"),
    Var("baud", "parameter", "Serial line speed", "bit/s", 9600.0),
    Var("data_bits", "parameter", "UART data bits (5-8)", start=8, type="Integer"),
    Var("parity", "parameter", "UART parity: N, E, O, M or S (pyserial's names)", start="N", type="String"),
    Var("stop_bits", "parameter", "UART stop bits: 1, 1.5 or 2", "1", 1.0),
    Var("turnaround", "parameter", "Controller turnaround: request received to answer start (AB3418 T2)", "s", 0.010),
    Var("fcs_msb_first", "parameter", "Send the FCS high byte first (default low byte first, RFC 1662 / ANCHORS S6)",
        start=False, type="Boolean"),
    Var("max_pending_requests", "parameter", "Requests that may wait for or be in their answer; more are dropped (flood)",
        start=1, type="Integer"),
    Var("rx_buffer_size", "parameter", "Bytes that may wait to be sent to the controller; more are dropped", start=65536, type="Integer"),
    Var("max_frame", "parameter", "Largest frame between flags, unstuffed; longer is an oversize error", start=ab3418.MAX_FRAME, type="Integer"),
)
_INPUTS = (
    Var("preempt_call", "input", "Hard-wired preemption call (e.g. an emergency-vehicle detector)", start=False, type="Boolean"),
    *(Var(f"call_{p}", "input", f"Detector call for phase {p} (actuated mode)", start=False, type="Boolean") for p in PHASES),
    Var("serial_rx_hex", "input", "Bytes reaching the controller's receive pin at this communication point, hex; "
        "consumed by the next step", start="", type="String"),
)
_OUTPUTS = tuple(
    var
    for p in PHASES
    for var in (
        Var(f"state_{p}", "output", f"Signal group {p}: J2735 MovementPhaseState (1 dark, 3 red, 5/6 green, 7/8 yellow)",
            type="Integer"),
        Var(f"min_end_{p}", "output", f"Signal group {p}: earliest time its state changes (J2735 minEndTime; -1 unknown)",
            "s", variability="discrete"),
        Var(f"max_end_{p}", "output", f"Signal group {p}: latest time its state changes (J2735 maxEndTime; -1 unknown)",
            "s", variability="discrete"),
    )
) + (
    Var("phase_r1", "output", "Ring-1 phase timing (green, yellow or red clearance); 0 = none", type="Integer"),
    Var("phase_r2", "output", "Ring-2 phase timing (green, yellow or red clearance); 0 = none", type="Integer"),
    Var("cycle_time", "output", "Local cycle clock", "s"),
    Var("preempt_state", "output", "Preemption: 0 not active, 1 entry, 2 dwell, 3 exit", type="Integer"),
    Var("serial_tx_hex", "output", "Bytes the controller sent during the last step, hex", type="String"),
    Var("serial_tx_end_time", "output", "When the last byte of serial_tx_hex left the line (-1 before any)", "s",
        variability="discrete"),
    Var("serial_tx_bytes", "output", "Bytes sent since the start", "byte", type="Integer"),
    Var("serial_rx_bytes", "output", "Bytes received since the start (stop bit done)", "byte", type="Integer"),
    Var("serial_rx_end_time", "output", "When the last received byte arrived (-1 before any)", "s", variability="discrete"),
    Var("serial_idle", "output", "Nothing on either line and no answer pending", type="Boolean"),
    *(Var(name, "output", description, type="Integer") for name, description in (
        ("frames_ok", "Well-formed frames addressed to this controller"),
        ("frames_ignored", "Well-formed frames for other stations"),
        ("responses_sent", "Answers sent (including error answers)"),
        ("err_fcs", "Frames dropped: FCS mismatch"),
        ("err_truncated", "Frames dropped: cut short or aborted"),
        ("err_garbage", "Byte runs dropped: not a frame (outside flags or no valid header)"),
        ("err_oversize", "Frames dropped: longer than max_frame"),
        ("err_unknown_type", "Frames of a type the controller does not know (request types get an error answer)"),
        ("err_bad_request", "Known requests with a wrong length or value (error answer)"),
        ("err_overrun", "Requests dropped: arrived while max_pending_requests were being answered"),
        ("err_rx_overflow", "Bytes dropped: more than rx_buffer_size waiting for the line"),
    )),
)
assert {v.name for v in _OUTPUTS} >= set(COUNTERS)


def _unknown(t):
    return -1.0 if t is None else float(t)


class TrafficLightController(V2iSlave):
    """NEMA dual-ring controller, NTCIP 1202 preemption, RS-232 AB3418-like serial port."""

    DESCRIPTION = (
        "NEMA dual-ring, barrier traffic-signal controller (8 phases; fixed time or actuated) with NTCIP 1202 "
        "preemption, SPaT outputs per signal group, and an RS-232 port with UART timing speaking an AB3418-like "
        "protocol (GetShortStatus, GetLongStatus8, SetPreempt) through hex String variables."
    )
    VARIABLES = _INPUTS + _PLAN + _PREEMPT + _SERIAL + _OUTPUTS
    DEFAULT_STEP = 0.01

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.model: TrafficLightModel | None = None
        self.start_time = 0.0

    def setup_experiment(self, start_time, stop_time, tolerance):
        self.start_time = float(start_time or 0.0)

    def plan(self) -> TimingPlan:
        v = self.values
        phases = {p: PhaseTiming(split=v[f"split_{p}"], min_green=v[f"min_green_{p}"], yellow=v[f"yellow_{p}"],
                                 red_clear=v[f"red_clear_{p}"], max_green=v[f"max_green_{p}"],
                                 passage=v[f"passage_{p}"]) for p in PHASES}
        preempt = PreemptConfig(
            enabled=v["preempt_enabled"], delay=v["preempt_delay"], min_green=v["preempt_min_green"],
            dwell=v["preempt_dwell"], max_presence=v["preempt_max_presence"],
            enter_yellow=v["preempt_enter_yellow"], enter_red=v["preempt_enter_red"],
            dwell_phases=(v["preempt_dwell_phase_r1"], v["preempt_dwell_phase_r2"]),
            exit_phases=(v["preempt_exit_phase_r1"], v["preempt_exit_phase_r2"]))
        return TimingPlan(phases, cycle=v["cycle"], offset=v["offset"], actuated=v["actuated"],
                          permissive=v["permissive_phases"], preempt=preempt)

    def initialize(self) -> None:
        v = self.values
        plan = self.plan()
        try:
            plan.validate()
        except PlanError as exc:
            raise ValueError(f"TrafficLightController parameter {exc}") from None
        for warning in plan.mutcd_warnings():
            self.log(f"MUTCD guidance (ANCHORS T1): {warning}", Fmi2Status.warning)
        uart = UartConfig(baud=v["baud"], data_bits=v["data_bits"], parity=v["parity"].upper(),
                          stop_bits=v["stop_bits"])
        self.model = TrafficLightModel(
            plan, uart, station=v["station"], turnaround=v["turnaround"], max_pending=v["max_pending_requests"],
            fcs_order=ab3418.MSB_FIRST if v["fcs_msb_first"] else ab3418.LSB_FIRST, max_frame=v["max_frame"],
            rx_buffer=v["rx_buffer_size"], t0=self.start_time)
        rx = self._take_rx()
        if rx:  # a start value: on the line from the start time
            self.model.rx.send(rx, self.start_time)
        self._publish(b"")

    def _take_rx(self) -> bytes:
        text = self.values["serial_rx_hex"]
        self.values["serial_rx_hex"] = ""
        if not text.strip():
            return b""
        try:
            return bytes.fromhex(text)
        except ValueError:
            raise ValueError(f"serial_rx_hex is not hexadecimal bytes: {text[:40]!r}") from None

    def step(self, t: float, dt: float) -> None:
        v = self.values
        rx = self._take_rx()
        calls = {p: v[f"call_{p}"] for p in PHASES}
        sent = self.model.step(t, dt, calls, v["preempt_call"], rx)
        self._publish(sent)

    def _publish(self, sent: bytes) -> None:
        m, v = self.model, self.values
        ctl = m.controller
        mins, maxs = ctl.change_bounds()
        for p in PHASES:
            v[f"state_{p}"] = ctl.movement_state(p)
            v[f"min_end_{p}"] = _unknown(mins[p])
            v[f"max_end_{p}"] = _unknown(maxs[p])
        v["phase_r1"], v["phase_r2"] = ctl.ring_phase(0), ctl.ring_phase(1)
        v["cycle_time"] = ctl.cycle_time()
        v["preempt_state"] = ctl.pstate
        v["serial_tx_hex"] = sent.hex()
        v["serial_tx_end_time"] = m.tx_end_time
        v["serial_tx_bytes"], v["serial_rx_bytes"] = m.tx_bytes, m.rx_bytes
        v["serial_rx_end_time"] = m.rx_end_time
        v["serial_idle"] = m.idle
        for name, count in m.counters.items():
            v[name] = count
