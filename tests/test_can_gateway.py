"""The CAN gateway's decision core alone (no bus, thread or FMU): which command drives the vehicle when,
the echo hold-until and repeats, the command-timeout policies, EMERGENCY_STOP and MANUAL, its statistics."""
from __future__ import annotations

import pytest

from bridges.can.codec import AppState, CavCommand, Mode
from master.links.can_gateway import Actuation, Gateway, StatusFrame

H = 0.01
BASELINE = (0.5, 0.05, False)  # the vehicle's own inputs before the first command


def gateway(sync: str = "echo", *, timeout: float = 0.05, on_timeout: str = "brake",
            log: list | None = None) -> Gateway:
    g = Gateway(sync, H, 0.0, BASELINE, command_timeout_s=timeout, on_timeout=on_timeout, timeout_accel=-4.0,
                estop_accel=-8.0, log=log.append if log is not None else None)
    assert g.start() == Actuation(0.0, "initial", Mode.MANUAL, 0.5, 0.05, False, None, True)
    return g


def cmd(accel: float, counter: int, echo: int = 0, steer: float = 0.0, mode: Mode = Mode.AUTO) -> CavCommand:
    return CavCommand(accel, steer, mode, False, echo, counter)


def written(a: Actuation | None) -> tuple | None:
    """The part of an actuation that reaches the vehicle and can-applied.csv."""
    if a is None:
        return None
    return (a.t, a.event, a.mode, a.accel, a.steer, a.reverse, a.command.counter if a.command else None,
            a.basis_t, a.inputs_changed)


# -- echo: t + one step ---------------------------------------------------------------------------------
def test_echo_applies_the_answer_to_status_t_at_t_plus_h_and_not_before():
    g = gateway("echo", timeout=1.0)
    g.status_sent(0, 0.0)
    g.received(cmd(2.0, 1, echo=0), rx_time=100.0)  # the app answered before the step from 0 even ended
    assert g.awaited(0.0) is None
    assert g.reach(0.0) is None  # held back: the baseline drives [0, h)
    assert written(g.reach(0.01)) == (0.01, "command", Mode.AUTO, 2.0, 0.0, False, 1, 0.0, True)

    g.status_sent(1, 0.02)  # after the step that ends at 0.02
    assert g.reach(0.02) is None  # its answer is due at 0.03 only
    assert g.awaited(0.03) == StatusFrame(1, 0.02)  # the master must wait for it before stepping from 0.03
    g.received(cmd(1.5, 2, echo=1, steer=0.1), rx_time=101.0)
    assert g.awaited(0.03) is None
    a = g.reach(0.03)
    assert written(a) == (0.03, "command", Mode.AUTO, 1.5, 0.1, False, 2, 0.02, True)
    assert a.source.rx_time == 101.0
    s = g.stats()
    assert (s["commands_received"], s["commands_applied"], s["commands_superseded"]) == (2, 2, 0)
    ages = s["actuation_age_s"]  # t_applied - t_status: one step each
    assert ages["n"] == 2 and ages["min"] == pytest.approx(H, abs=1e-12) and ages["max"] == pytest.approx(H, abs=1e-12)


def test_echo_ignores_a_repeat_answer_to_the_same_status():
    g = gateway("echo", timeout=1.0)
    g.status_sent(0, 0.0)
    g.received(cmd(2.0, 1, echo=0), 0.0)
    g.received(cmd(-3.0, 2, echo=0), 0.0)  # a second answer to status 0: not applied
    assert written(g.reach(0.01)) == (0.01, "command", Mode.AUTO, 2.0, 0.0, False, 1, 0.0, True)
    s = g.stats()
    assert (s["commands_received"], s["commands_repeat_ignored"], s["commands_applied"]) == (2, 1, 1)
    g.status_sent(0, 0.02)  # the 8-bit counter came round: a new status with the same Counter
    g.received(cmd(-3.0, 3, echo=0), 0.0)
    assert written(g.reach(0.03)) == (0.03, "command", Mode.AUTO, -3.0, 0.0, False, 3, 0.02, True)
    assert g.stats()["commands_repeat_ignored"] == 1


def test_echo_does_not_wait_before_the_app_has_sent_anything_nor_after_it_lost_its_turn():
    g = gateway("echo", timeout=1.0)
    g.status_sent(0, 0.0)
    assert g.awaited(0.01) is None  # no command yet: the app may not be up
    g.received(cmd(1.0, 1, echo=0), 0.0)
    g.reach(0.01)
    g.status_sent(1, 0.02)
    assert g.awaited(0.03) == StatusFrame(1, 0.02)
    g.lost_turn()  # sync_timeout_s passed without the answer
    assert g.awaited(0.03) is None
    g.reach(0.03)
    g.status_sent(2, 0.04)
    assert g.awaited(0.05) is None  # runs free until the app sends again
    g.received(cmd(1.0, 2, echo=2), 0.0)
    g.reach(0.05)
    g.status_sent(3, 0.06)
    assert g.awaited(0.07) == StatusFrame(3, 0.06)


def test_a_held_answer_is_not_superseded_by_a_command_applied_before_it_is_due():
    g = gateway("echo", timeout=1.0)
    g.status_sent(0, 0.0)
    g.received(cmd(2.0, 1, echo=0), 0.0)  # due at 0.01
    g.received(cmd(-1.0, 2, echo=99), 0.0)  # unknown echo: applies at once
    assert written(g.reach(0.0)) == (0.0, "command", Mode.AUTO, -1.0, 0.0, False, 2, None, True)
    assert written(g.reach(0.01)) == (0.01, "command", Mode.AUTO, 2.0, 0.0, False, 1, 0.0, True)
    s = g.stats()
    assert (s["commands_applied"], s["commands_superseded"], s["commands_unsynced"]) == (2, 0, 1)


# -- free: the latest before the point ------------------------------------------------------------------------
def test_free_applies_an_unsynced_command_at_the_next_point():
    g = gateway("free", timeout=1.0)
    g.status_sent(0, 0.0)
    g.received(cmd(1.0, 1, echo=77), 5.0)  # echoes no status the gateway sent
    a = g.reach(0.0)
    assert written(a) == (0.0, "command", Mode.AUTO, 1.0, 0.0, False, 1, None, True)
    assert a.source.rx_time == 5.0
    s = g.stats()
    assert (s["commands_unsynced"], s["commands_applied"], s["actuation_age_s"]) == (1, 1, None)


def test_free_applies_a_synced_answer_at_once_and_records_its_age():
    g = gateway("free", timeout=1.0)
    g.status_sent(4, 0.02)
    g.received(cmd(1.0, 1, echo=4), 0.0)
    assert written(g.reach(0.02)) == (0.02, "command", Mode.AUTO, 1.0, 0.0, False, 1, 0.02, True)
    assert g.stats()["actuation_age_s"] == {"min": 0.0, "max": 0.0, "mean": 0.0, "n": 1}


def test_superseded_commands_are_counted_and_the_latest_applies():
    g = gateway("free", timeout=1.0)
    for counter, accel in ((1, 1.0), (2, 2.0), (3, 3.0)):
        g.received(cmd(accel, counter, echo=50), 0.0)
    assert written(g.reach(0.0)) == (0.0, "command", Mode.AUTO, 3.0, 0.0, False, 3, None, True)
    assert g.reach(0.01) is None  # nothing new: the inputs stay
    g.received(cmd(3.0, 4, echo=50), 0.0)  # the same request again: still a command row
    assert written(g.reach(0.02)) == (0.02, "command", Mode.AUTO, 3.0, 0.0, False, 4, None, False)
    s = g.stats()
    assert (s["commands_received"], s["commands_applied"], s["commands_superseded"]) == (4, 2, 2)


# -- modes ------------------------------------------------------------------------------------------------
def test_emergency_stop_brakes_with_estop_accel_whatever_it_asks():
    g = gateway("free", timeout=1.0)
    g.received(cmd(-1.0, 1, steer=0.2, mode=Mode.EMERGENCY_STOP), 0.0)
    assert written(g.reach(0.0)) == (0.0, "command", Mode.EMERGENCY_STOP, -8.0, 0.2, False, 1, None, True)
    assert g.reported() == (Mode.EMERGENCY_STOP, False)


def test_manual_gives_the_vehicle_its_own_inputs_back():
    g = gateway("free", timeout=1.0)
    assert g.reported() == (Mode.MANUAL, False)
    g.received(cmd(2.0, 1, steer=0.3), 0.0)
    g.reach(0.0)
    assert g.reported() == (Mode.AUTO, False)
    g.received(cmd(3.0, 2, steer=0.3, mode=Mode.MANUAL), 0.0)
    assert written(g.reach(0.01)) == (0.01, "command", Mode.MANUAL, 0.5, 0.05, False, 2, None, True)
    assert g.reported() == (Mode.MANUAL, False)


def test_heartbeats_are_counted_with_the_last_state():
    g = gateway()
    g.heartbeat(AppState.READY)
    g.heartbeat(AppState.ENGAGED)
    s = g.stats()
    assert (s["heartbeats"], s["last_app_state"]) == (2, "ENGAGED")


# -- command timeout -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("policy, mode, expected", [
    ("brake", Mode.AUTO, (-4.0, 0.1, False)),
    ("zero_accel", Mode.AUTO, (0.0, 0.1, False)),
    ("hold", Mode.AUTO, (2.0, 0.1, False)),
    ("manual", Mode.AUTO, BASELINE),
    ("brake", Mode.EMERGENCY_STOP, (-8.0, 0.1, False)),  # min(estop, timeout_accel)
    ("zero_accel", Mode.EMERGENCY_STOP, (-8.0, 0.1, False)),  # an emergency stop is never released to 0
    ("hold", Mode.EMERGENCY_STOP, (-8.0, 0.1, False)),
    ("manual", Mode.EMERGENCY_STOP, BASELINE),
    ("brake", Mode.MANUAL, (-4.0, 0.05, False)),
    ("zero_accel", Mode.MANUAL, (0.0, 0.05, False)),
    ("hold", Mode.MANUAL, BASELINE),
])
def test_command_timeout_applies_the_policy_until_a_command_comes_again(policy, mode, expected):
    events = []
    g = gateway("free", timeout=0.05, on_timeout=policy, log=events)
    g.received(cmd(2.0, 1, steer=0.1, mode=mode), 0.0)
    before = written(g.reach(0.0))[3:6]
    for t in (0.01, 0.02, 0.03, 0.04):
        assert g.reach(t) is None  # the command holds
    a = g.reach(0.05)  # command_timeout_s after the last command: the fallback
    assert written(a) == (0.05, "fallback", Mode.FALLBACK, *expected, None, None, expected != before)
    assert g.reported() == (Mode.FALLBACK, False)
    assert events == [{"t": 0.05, "event": "command_timeout", "policy": policy, "last_command_t": 0.0}]
    for t in (0.06, 0.07):
        assert g.reach(t) is None
    s = g.stats()  # an open fallback counts up to the last point reached
    assert (s["timeouts"], s["fallback_s"]) == (1, 0.07 - 0.05)

    g.received(cmd(1.0, 2), 0.0)
    assert written(g.reach(0.08)) == (0.08, "command", Mode.AUTO, 1.0, 0.0, False, 2, None, True)
    g.reach(0.09)
    s = g.stats()
    assert (s["timeouts"], s["fallback_s"], s["commands_applied"]) == (1, 0.08 - 0.05, 2)
    assert len(events) == 1


def test_no_fallback_before_the_first_command():
    g = gateway("free", timeout=0.05)
    for k in range(20):
        assert g.reach(k * H) is None  # the vehicle keeps its own inputs until the app speaks
    assert g.stats()["timeouts"] == 0


def test_a_second_silence_is_a_second_timeout():
    g = gateway("free", timeout=0.05, on_timeout="zero_accel")
    g.received(cmd(2.0, 1), 0.0)
    g.reach(0.0)
    assert g.reach(0.05).event == "fallback"
    g.received(cmd(2.0, 2), 0.0)
    assert g.reach(0.1).event == "command"
    assert g.reach(0.15).event == "fallback"
    g.reach(0.2)
    s = g.stats()
    assert (s["timeouts"], s["fallback_s"]) == (2, (0.1 - 0.05) + (0.2 - 0.15))


# -- set-up ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("sync, on_timeout", [("lockstep", "brake"), ("echo", "pray")])
def test_unknown_sync_or_policy_is_refused(sync, on_timeout):
    with pytest.raises(ValueError):
        Gateway(sync, H, 0.0, BASELINE, command_timeout_s=0.1, on_timeout=on_timeout, timeout_accel=-4.0,
                estop_accel=-8.0)
