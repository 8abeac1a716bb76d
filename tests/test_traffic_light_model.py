"""The traffic-light model in plain Python: plans and NTCIP ranges (T1, T4), ITE helpers (T2, T3),
UART timing (S1-S3), the dual ring in fixed-time and actuated operation, preemption (T5), and the
AB3418 endpoint. The same behaviour through the built FMU is in test_traffic_light_fmu.py."""
from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridges import ab3418 as a
from fmus.traffic_light.controller import Controller
from fmus.traffic_light.model import TrafficLightModel
from fmus.traffic_light.plan import (MPH, PHASES, PhaseTiming, PlanError, PreemptConfig, TimingPlan,
                                     design_all_red, design_yellow, ite_all_red, ite_all_red_us, ite_yellow,
                                     ite_yellow_us)
from fmus.traffic_light.preemption import DWELL, ENTRY, EXIT, NOT_ACTIVE
from fmus.traffic_light.uart import UartConfig

Y, RC = 3.3, 1.2


def two_phase(actuated=False, **preempt) -> TimingPlan:
    """4-approach, 2-phase plan: phases 2+6 (group A), 4+8 (group B), cycle 60 s."""
    phases = {p: PhaseTiming(split=30.0 if p % 2 == 0 else 0.0, min_green=5.0, yellow=Y, red_clear=RC,
                             max_green=20.0, passage=2.0) for p in PHASES}
    cfg = dict(min_green=3.0, dwell=10.0, dwell_phases=(4, 8), exit_phases=(2, 6))
    cfg.update(preempt)
    return TimingPlan(phases, cycle=60.0, offset=0.0, actuated=actuated, preempt=PreemptConfig(**cfg))


def timeline(ctl: Controller, t_end: float, h: float = 0.01, inputs=None):
    """[(time, phase, display)] of every display change, sampled at step ends."""
    changes, before = [], {p: ctl.display(p) for p in PHASES}
    k = round(ctl.now / h)
    while k * h < t_end - 1e-9:
        if inputs:
            inputs(ctl, k * h)
        ctl.advance((k + 1) * h)
        k += 1
        for p in PHASES:
            d = ctl.display(p)
            if d != before[p]:
                changes.append((round(k * h, 6), p, d))
                before[p] = d
    return changes


# -- plans, NTCIP ranges, ITE ----------------------------------------------------------------
def test_T4_yellow_range_is_ntcip_tenths_30_to_255():
    """ANCHORS T4: phaseYellowChange is 30..255 tenths of a second; errors name the parameter."""
    plan = two_phase()
    for bad, why in ((2.9, "out of range 3..25.5"), (25.6, "out of range"), (3.25, "tenths")):
        phases = dict(plan.phases)
        phases[4] = dataclasses.replace(phases[4], yellow=bad)
        with pytest.raises(PlanError, match=rf"^yellow_4 = .*{why}"):
            dataclasses.replace(plan, phases=phases).validate()
    for ok in (3.0, 25.5):  # both ends accepted (a 120 s cycle leaves room for a 25.5 s yellow)
        phases = {p: dataclasses.replace(t, split=2 * t.split) for p, t in plan.phases.items()}
        phases[4] = dataclasses.replace(phases[4], yellow=ok)
        dataclasses.replace(plan, phases=phases, cycle=120.0).validate()


def test_plan_consistency_errors_name_the_parameter():
    plan = two_phase()
    cases = [
        ({6: dict(split=32.0)}, r"^split_1: the splits of phases 1\+2 / 5\+6 must reach the barrier together"),
        ({2: dict(split=8.0), 6: dict(split=8.0)}, r"^split_2 = 8 s: shorter than min_green_2"),
        ({3: dict(min_green=0.5)}, r"^min_green_3 = 0.5 s: out of range 1..255"),
        ({8: dict(red_clear=26.0)}, r"^red_clear_8 = 26 s: out of range"),
    ]
    for changes, message in cases:
        phases = {p: dataclasses.replace(t, **changes.get(p, {})) for p, t in plan.phases.items()}
        with pytest.raises(PlanError, match=message):
            dataclasses.replace(plan, phases=phases).validate()
    with pytest.raises(PlanError, match=r"^cycle = 70 s: the splits of ring 1"):
        dataclasses.replace(plan, cycle=70.0).validate()
    with pytest.raises(PlanError, match=r"^preempt_dwell_phase_r1 = 3: phase 3 is not used"):
        dataclasses.replace(plan, preempt=PreemptConfig(dwell_phases=(3, 8), exit_phases=(2, 6))).validate()
    with pytest.raises(PlanError, match=r"^preempt_exit_phase_r2 = 8: phases 2 and 8 are on opposite sides"):
        dataclasses.replace(plan, preempt=PreemptConfig(dwell_phases=(4, 8), exit_phases=(2, 8))).validate()


def test_T1_mutcd_guidance_is_reported_and_design_helpers_respect_it():
    """ANCHORS T1: yellow 3-6 s, red clearance <= 6 s (guidance: warned, not rejected)."""
    plan = two_phase()
    assert plan.mutcd_warnings() == []
    phases = dict(plan.phases)
    phases[2] = dataclasses.replace(phases[2], yellow=7.0, red_clear=6.5, split=30.0)
    phases[4] = dataclasses.replace(phases[4], split=30.0)
    warnings = dataclasses.replace(plan, phases=phases).mutcd_warnings()
    assert warnings == ["yellow_2 = 7 s is outside the MUTCD 3-6 s guidance",
                        "red_clear_2 = 6.5 s exceeds the MUTCD 6 s guidance"]
    for speed_kmh in (20, 30, 50, 70, 100, 130):
        assert 3.0 <= design_yellow(speed_kmh / 3.6) <= 6.0
        assert design_all_red(40.0, speed_kmh / 3.6) <= 6.0
    assert design_yellow(25 * MPH) == 3.0  # the ITE value (2.83 s) is raised to MUTCD's 3 s
    assert design_yellow(80 * MPH) == 6.0  # and 6.9 s is capped at 6 s


def test_T2_ite_yellow():
    """ANCHORS T2: Y = t + v / (2a + 2Gg), t = 1 s, level: 35 mph -> 3.57 s, 45 mph -> 4.31 s (ITE's US form)."""
    assert ite_yellow_us(35) == pytest.approx(3.57, abs=0.005)
    assert ite_yellow_us(45) == pytest.approx(4.31, abs=0.005)
    # the SI form differs only by ITE's 1.47 ft/s per mph (vs 22/15) and a = 10 ft/s2 vs 3.05 m/s2
    for mph in (35, 45):
        assert (ite_yellow_us(mph) - 1) / (ite_yellow(mph * MPH) - 1) == pytest.approx(1.47 / (22 / 15) * 3.05 / 3.048, rel=1e-9)
    assert ite_yellow(15.0, grade=0.04) < ite_yellow(15.0) < ite_yellow(15.0, grade=-0.04)


def test_T3_ite_all_red():
    """ANCHORS T3: R = (W + L) / v, 35 mph, W = 60 ft, L = 20 ft -> 1.55 s (ITE's US form)."""
    assert ite_all_red_us(60, 35, 20) == pytest.approx(1.55, abs=0.005)
    assert ite_all_red(60 * 0.3048, 35 * MPH, 20 * 0.3048) == pytest.approx(80 * 0.3048 / (35 * MPH), rel=1e-12)


# -- UART ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("baud, ms", [(9600, 1.0417), (19200, 0.5208), (115200, 0.0868)])
def test_S1_character_time_8N1(baud, ms):
    """ANCHORS S1: one 8N1 character is 10 / baud s."""
    assert UartConfig(baud=baud).char_time * 1e3 == pytest.approx(ms, abs=5e-5)


def test_S2_S3_1024_bytes_at_9600_8N1():
    """ANCHORS S2: 1024 bytes at 9600 8N1 take 1066.67 ms; S3: of the standard settings only 9600 8N1
    lies within 1 % of the seed paper's 1064.3 ms (8 data bits: AB3418 bytes are 8-bit)."""
    m = TrafficLightModel(two_phase())
    m.step(0.0, 2.0, rx=bytes(1024))
    assert m.rx_bytes == 1024
    assert m.rx_end_time * 1e3 == pytest.approx(1066.67, abs=0.005)
    close = [(baud, bits, parity, stop) for baud in (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)
             for bits in (8,) for parity in ("N", "E", "O") for stop in (1, 1.5, 2)
             if abs(1024 * UartConfig(baud, bits, parity, stop).char_time - 1.0643) / 1.0643 < 0.01]
    assert close == [(9600, 8, "N", 1)], close


def test_receive_line_times_each_byte_and_queues_behind_busy_line():
    m = TrafficLightModel(two_phase())
    c = 10 / 9600
    m.step(0.0, 0.001, rx=bytes(3))      # bytes 1-3 end at c, 2c, 3c
    assert m.rx_bytes == 0               # the first stop bit is at 1.04 ms
    m.step(0.001, 0.001, rx=bytes(2))    # written while the line is busy: they queue
    assert m.rx_bytes == 1 and m.rx_end_time == pytest.approx(c, abs=1e-12)
    m.step(0.002, 0.01)
    assert m.rx_bytes == 5 and m.rx_end_time == pytest.approx(5 * c, abs=1e-12)
    m.step(0.012, 0.01, rx=bytes(1))     # line idle again: a fresh burst
    m.step(0.022, 0.01)
    assert m.rx_end_time == pytest.approx(0.012 + c, abs=1e-12)


def test_uart_framing_parameters():
    assert UartConfig(9600, 7, "E", 2).char_time == pytest.approx(11 / 9600)
    assert UartConfig(9600, 8, "N", 1.5).bits_per_char == 10.5
    for kwargs, name in ((dict(data_bits=9), "data_bits"), (dict(parity="X"), "parity"),
                         (dict(stop_bits=3), "stop_bits"), (dict(baud=0), "baud")):
        with pytest.raises(ValueError, match=f"^{name} = "):
            UartConfig(**kwargs).validate()


# -- the dual ring ----------------------------------------------------------------------------------
def expected_fixed_cycle(plan: TimingPlan, t0: float = 0.0):
    """Display changes of one undisturbed cycle, from the splits alone."""
    out = []
    for ring_phases in (((1, 2), (3, 4)), ((5, 6), (7, 8))):
        t = t0
        for group in ring_phases:
            for p in group:
                if not plan.used(p):
                    continue
                pt = plan.phases[p]
                out += [(t, p, "G"), (t + pt.split - pt.yellow - pt.red_clear, p, "Y"),
                        (t + pt.split - pt.red_clear, p, "R")]
                t += pt.split
    return sorted((round(t, 6), p, d) for t, p, d in out)


def test_fixed_time_two_phase_cycle_phase_by_phase():
    plan = two_phase()
    ctl = Controller(plan, 0.0)
    assert [ctl.display(p) for p in PHASES] == ["dark", "G", "dark", "R", "dark", "G", "dark", "R"]
    changes = timeline(ctl, 120.0)
    expected = [c for start in (0.0, 60.0, 120.0) for c in expected_fixed_cycle(plan, start) if 0 < c[0] <= 120.0]
    assert changes == expected


def test_fixed_time_offset_starts_mid_cycle():
    plan = dataclasses.replace(two_phase(), offset=10.0)
    ctl = Controller(plan, 0.0)  # local zero at t = 10: at t = 0 the cycle is at 50 s (phase 4 green)
    assert ctl.cycle_time() == pytest.approx(50.0)
    assert ctl.display(4) == "G" and ctl.display(2) == "R"
    mins, maxs = ctl.change_bounds()
    assert mins[4] == maxs[4] == pytest.approx(10.0 - 30.0 + 25.5)  # green ends at 5.5 s


def test_change_bounds_fixed_time():
    ctl = Controller(two_phase(), 0.0)
    ctl.advance(1.0)
    mins, maxs = ctl.change_bounds()
    assert mins[2] == maxs[2] == pytest.approx(25.5)   # green -> yellow
    assert mins[4] == maxs[4] == pytest.approx(30.0)   # red -> green
    assert mins[1] is None and maxs[1] is None         # unused phase: dark forever


def test_actuated_gap_out_max_out_and_simultaneous_gap_out():
    plan = two_phase(actuated=True)
    ctl = Controller(plan, 0.0)  # no calls: both rings gap out at min green (5 s)
    changes = timeline(ctl, 5.5)
    assert (5.0, 2, "Y") in changes and (5.0, 6, "Y") in changes

    ctl = Controller(plan, 0.0)  # calls on 2 and 6 until t = 8: gap-out at 8 + passage 2 = 10 s
    changes = timeline(ctl, 11.0, inputs=lambda c, t: c.set_inputs({2: t < 8, 6: t < 8}))
    assert [c for c in changes if c[2] == "Y"] == [(10.0, 2, "Y"), (10.0, 6, "Y")]

    ctl = Controller(plan, 0.0)  # call held on 6 only: 2 is ready at 5 s but holds for 6 (max-out 20 s)
    mins, maxs = ctl.change_bounds()
    assert mins[2] == pytest.approx(5.0) and maxs[2] == pytest.approx(20.0)
    changes = timeline(ctl, 25.0, inputs=lambda c, t: c.set_inputs({6: True}))
    assert [c for c in changes if c[2] == "Y"] == [(20.0, 2, "Y"), (20.0, 6, "Y")]
    assert (20.0 + Y + RC, 4, "G") in changes  # both rings cross the barrier together


# -- preemption (T5) ------------------------------------------------------------------------------
def run_preempt(plan, call_on, call_off, t_end, h=0.01):
    ctl = Controller(plan, 0.0)
    states = []

    def inputs(c, t):
        c.set_inputs(preempt=call_on - 1e-9 <= t < call_off - 1e-9)
        states.append((round(t, 6), c.pstate))

    changes = timeline(ctl, t_end, h, inputs)
    pchanges = [(t, s) for (t, s), (_, prev) in zip(states[1:], states) if s != prev]
    return ctl, changes, pchanges


def test_T5_preemption_entry_dwell_exit_timeline():
    """ANCHORS T5: green 2+6 running 10 s (> min(5, 3)) ends at once; its yellow 3.3 s and red 1.2 s run in
    full; 4+8 dwell from 14.5 s for >= 10 s; exit clears 4+8 and resumes the plan at 2+6."""
    plan = two_phase()
    ctl, changes, pstates = run_preempt(plan, call_on=10.0, call_off=12.0, t_end=60.0)
    entry, dwell = 10.0, 10.0 + Y + RC
    exit_ = dwell + 10.0
    back = exit_ + Y + RC
    # sampled at step ends: what an input change starts shows one step later, timed events at their instant
    assert pstates == [(10.01, ENTRY), (round(dwell, 6), DWELL), (round(exit_, 6), EXIT), (round(back, 6), NOT_ACTIVE)]
    assert changes[:6] == [(10.01, 2, "Y"), (10.01, 6, "Y"), (round(entry + Y, 6), 2, "R"),
                           (round(entry + Y, 6), 6, "R"), (round(dwell, 6), 4, "G"), (round(dwell, 6), 8, "G")]
    assert changes[6:12] == [(round(exit_, 6), 4, "Y"), (round(exit_, 6), 8, "Y"), (round(exit_ + Y, 6), 4, "R"),
                             (round(exit_ + Y, 6), 8, "R"), (round(back, 6), 2, "G"), (round(back, 6), 6, "G")]
    # normal operation resumes from 2+6 with a full green
    assert changes[12:14] == [(round(back + 25.5, 6), 2, "Y"), (round(back + 25.5, 6), 6, "Y")]


def test_T5_running_green_held_for_min_of_phase_and_preempt_min_green():
    plan = two_phase()  # phase min green 5 s, preempt min green 3 s: held until 3 s of green
    _, changes, _ = run_preempt(plan, call_on=1.0, call_off=2.0, t_end=10.0)
    assert changes[:2] == [(3.0, 2, "Y"), (3.0, 6, "Y")]
    plan = two_phase(min_green=8.0)  # min(5, 8) = 5 s
    _, changes, _ = run_preempt(plan, call_on=1.0, call_off=2.0, t_end=10.0)
    assert changes[:2] == [(5.0, 2, "Y"), (5.0, 6, "Y")]


def test_T5_clearance_not_shortened_below_phase_values():
    for enter_yellow, enter_red, y, r in ((3.0, 0.5, Y, RC), (4.0, 2.0, 4.0, 2.0)):
        plan = two_phase(enter_yellow=enter_yellow, enter_red=enter_red)
        _, changes, _ = run_preempt(plan, call_on=10.0, call_off=11.0, t_end=20.0)
        assert changes[2] == (round(10.0 + y, 6), 2, "R")
        assert changes[4] == (round(10.0 + y + r, 6), 4, "G")
    # a yellow already running when the call comes finishes as it is
    _, changes, pstates = run_preempt(two_phase(), call_on=26.0, call_off=27.0, t_end=40.0)
    assert changes[:4] == [(25.5, 2, "Y"), (25.5, 6, "Y"), (28.8, 2, "R"), (28.8, 6, "R")]
    assert (30.0, 4, "G") in changes and pstates[1] == (30.0, DWELL)


def test_T5_dwell_lasts_while_the_call_persists():
    _, changes, pstates = run_preempt(two_phase(), call_on=10.0, call_off=40.0, t_end=50.0)
    assert (40.01, 4, "Y") in changes  # call dropped at 40 s, after the 10 s minimum dwell
    assert [s for _, s in pstates] == [ENTRY, DWELL, EXIT, NOT_ACTIVE]


def test_preempt_delay_and_max_presence():
    plan = two_phase(delay=2.0, max_presence=8.0)
    _, changes, pstates = run_preempt(plan, call_on=10.0, call_off=100.0, t_end=40.0)
    assert pstates[0] == (12.0, ENTRY)  # the delay expires at a scheduled instant
    assert (12.0, 2, "Y") in changes
    # the call is ignored after 8 s of presence (t = 18): dwell ends after its minimum 10 s
    dwell = 12.0 + Y + RC
    assert (round(dwell + 10.0, 6), 4, "Y") in changes


# -- the AB3418 endpoint -----------------------------------------------------------------------------
def exchange(m: TrafficLightModel, data: bytes, t: float, h: float = 0.001, until: float = 1.0):
    out = b""
    k = 0
    while t + k * h < t + until:
        out += m.step(t + k * h, h, rx=data if k == 0 else b"")
        k += 1
    return out, t + k * h


def test_S7_long_status_round_trip_time_in_the_model():
    """ANCHORS S7: GetLongStatus8 at 9600 8N1: 8 + 40 bytes of wire time (50.0 ms) + turnaround 10 ms."""
    m = TrafficLightModel(two_phase())
    m.step(0.0, 0.5)
    out, _ = exchange(m, a.request(a.GET_LONG_STATUS8), 0.5)
    assert len(out) == 40
    assert m.tx_end_time - 0.5 == pytest.approx(0.050 + 0.010, abs=1e-9)
    (frame,) = a.FrameDecoder().feed(out)
    status = a.LongStatus8.decode(frame.data)
    t_answer = 0.5 + 8 * 10 / 9600 + 0.010  # the status is taken when the answer starts
    assert frame.msg_type == 0xCC and status.greens == 0b00100010 and status.phase_a == 2
    assert a.from_tenths(status.ttc_a_min) == pytest.approx(25.5 - t_answer, abs=0.05)
    assert status.seq_number == 1 and status.preempt_state == NOT_ACTIVE


def test_set_preempt_over_serial_starts_preemption():
    m = TrafficLightModel(two_phase())
    m.step(0.0, 10.0)
    out, t = exchange(m, a.request(a.SET_PREEMPT, data=b"\x01"), 10.0, until=0.1)
    assert a.FrameDecoder().feed(out) == [a.Frame(0x05, a.CTRL_UI, 0xDB)]
    assert m.controller.pstate == ENTRY
    # the call took effect when the request had arrived: 9 bytes after 10.0 s
    assert m.controller.rings[0].t_start == pytest.approx(10.0 + 9 * 10 / 9600, abs=1e-9)
    out, t = exchange(m, a.request(a.SET_PREEMPT, data=b"\x00"), t, until=30.0)
    assert m.controller.pstate == NOT_ACTIVE and m.counters["responses_sent"] == 2


@settings(max_examples=60, deadline=None)
@given(chunks=st.lists(st.binary(max_size=120), min_size=1, max_size=8))
def test_any_bytes_on_the_line_never_disturb_the_plan(chunks):
    """Line noise of any kind: the endpoint never raises, every byte is accounted for, the plan runs on."""
    plan = two_phase()
    m, ref = TrafficLightModel(plan), Controller(plan, 0.0)
    for k, chunk in enumerate(chunks):
        m.step(k * 0.5, 0.5, rx=chunk)
        ref.advance((k + 1) * 0.5)
        assert [m.controller.display(p) for p in PHASES] == [ref.display(p) for p in PHASES]
    m.step(len(chunks) * 0.5, 2.0)
    assert m.rx_bytes == sum(len(c) for c in chunks)
    assert m.counters["responses_sent"] <= m.counters["frames_ok"]
