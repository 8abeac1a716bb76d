"""metrics.json's `preemption` section from a run folder's records alone (master/run/preemption.py): a small
synthetic run folder with the "evsp" trace records, the controller's columns and two vehicles."""
from __future__ import annotations

import pytest

from master.run.preemption import preemption_metrics

WORLD = """
[world.intersection]
road_width = 7.0
[[world.signals]]
name = "nb"
x = 5.0
y = 5.0
yaw = 270.0
signal_group = 2
[[world.signals]]
name = "eb"
x = 5.0
y = -5.0
yaw = 180.0
signal_group = 8
"""


def rows(ev_stop_s: float = 0.0, nb_start_y: float = -40.0):
    """ev eastbound at 10 m/s from x = -60 (waits ev_stop_s at x = -5); nb northbound at 10 m/s; phase 8 green
    from t = 4, phase 2 green until t = 3."""
    out, x, waited = [], -60.0, 0.0
    for k in range(1201):
        t = k * 0.01
        if x >= -5.0 and waited < ev_stop_s:
            waited += 0.01
            v = 0.0
        else:
            v = 10.0
            x += 10.0 * 0.01 if k else 0.0
        y_nb = nb_start_y + 10.0 * t
        out.append({"time": f"{t:.2f}", "tlc.state_8": "6" if t >= 4.0 else "3",
                    "tlc.state_2": "6" if t < 3.0 else "3", "ev.x": str(x), "ev.y": "-1.75", "ev.v": str(v),
                    "nb.x": "1.75", "nb.y": str(y_nb), "nb.v": "10.0"})
    return out


TRACES = [{"record": "evsp", "kind": "srm_sent", "t": 1.0, "srm": "request", "vehicle": "ev", "signal_group": 8},
          {"record": "evsp", "kind": "srm", "t": 1.0025},
          {"record": "evsp", "kind": "preempt_call", "t": 1.0025, "on": True},
          {"record": "evsp", "kind": "preempt_ack", "t": 1.05, "on": True, "ok": True, "request_bytes": 9,
           "answer_bytes": 8, "wire_s": 17 * 10 / 9600},
          {"record": "evsp", "kind": "status", "t": 4.07, "status": "granted"}]


def test_the_section_reads_requests_stages_delays_and_violations(tmp_path):
    (tmp_path / "scenario.resolved.toml").write_text(WORLD)
    m = preemption_metrics(tmp_path, TRACES, rows(ev_stop_s=2.0, nb_start_y=-40.0))
    assert m["granted"] and m["srm_to_green_ms"] == pytest.approx(3000.0)
    s = m["stages_ms"]
    assert s["srm_air"] == pytest.approx(2.5) and s["serial_round_trip"] == pytest.approx(47.5)
    assert s["serial_wire"] == pytest.approx(17 * 10 / 9600 * 1000, abs=1e-3)
    assert s["controller"] == pytest.approx(2950.0) and s["ssm"] == pytest.approx(70.0)
    assert m["ev"] == "ev" and m["ev_delay_s"] == pytest.approx(2.0, abs=0.02)
    assert m["ev_stopped_s"] == pytest.approx(2.0, abs=0.02)
    # nb reaches the box (y = -3.5) at t = 3.65: phase 2 is red from t = 3 -> one violation
    assert m["red_violations"] == 1 and m["red_violators"] == ["nb"]
    assert m["cross_delay_s"] == pytest.approx(0.0, abs=0.02)


def test_no_violation_when_the_cross_vehicle_enters_on_green_and_none_without_records(tmp_path):
    (tmp_path / "scenario.resolved.toml").write_text(WORLD)
    m = preemption_metrics(tmp_path, TRACES, rows(nb_start_y=-20.0))   # nb in the box at t = 1.65: green
    assert m["red_violations"] == 0 and m["ev_delay_s"] == pytest.approx(0.0, abs=0.02)
    assert preemption_metrics(tmp_path, [{"kind": "detections"}], rows()) is None


def test_the_console_verdict_and_the_report_show_the_section():
    from master.run.verdict import verdict_lines

    p = {"requested": True, "granted": True, "srm_to_green_ms": 5900.0, "ev": "ev", "ev_delay_s": 0.01,
         "ev_stopped_s": 0.0, "red_violations": 0, "stages_ms": {"srm_air": 2.546, "serial_wire": 17.708,
                                                                  "serial_request_bytes": 9, "ssm": None}}
    lines = verdict_lines({"preemption": p})
    assert lines[0] == ("preemption: granted — SRM to green 5900 ms; ev ev delay 0.01 s, stopped 0.00 s; "
                        "red violations 0")
    assert lines[1] == "  stages: srm_air 2.5 ms, serial_wire 17.7 ms"
    baseline = verdict_lines({"preemption": {"requested": False, "granted": False, "ev": "ev", "ev_delay_s": None,
                                             "ev_stopped_s": 0.0, "red_violations": 1, "stages_ms": {}}})
    assert baseline == ["preemption: not requested; ev ev delay n/a s, stopped 0.00 s; red violations 1"]
