"""master.run.metrics: latency stages from trace records joined with the CAN gateway's log, PDR, IPG, AoI."""
from __future__ import annotations

import json

import pytest

from bridges import v2x
from master.run.metrics import (Applications, aoi_metrics, applied_times, clock_bounds, latency_metrics, link_metrics,
                            read_jsonl, subject_deliveries, with_can_applied)


def record(frame, detect_end, send, arrival, command, counter):
    ns = v2x.stamp_ns
    return {"stamps": {v2x.FRAME: ns(frame), v2x.DETECT_END: ns(detect_end), v2x.SEND: ns(send),
                       v2x.AIR_ARRIVAL: ns(arrival), v2x.CAN_COMMAND: ns(command)}, "can_counter": counter}


def test_stages_and_e2e_join_the_command_counter_with_its_application():
    rows = [{"t": "1.05", "event": "command", "counter": "7"}, {"t": "1.07", "event": "mode", "counter": ""},
            {"t": "6.17", "event": "command", "counter": "7"},  # the counter wrapped: a later command
            {"t": "1.13", "event": "command", "counter": "9"}]
    applied = applied_times(rows)
    assert applied == Applications([(1.05, 7), (1.13, 9), (6.17, 7)])
    recs = [record(0.9, 0.93, 0.932, 0.9335, 1.04, 7), record(1.0, 1.03, 1.032, 1.0338, 1.12, 9)]
    assert with_can_applied(recs[0], applied)[v2x.CAN_APPLIED] == v2x.stamp_ns(1.05)
    lat = latency_metrics(recs, applied)
    assert lat["stage1"]["n"] == 2 and lat["stage1"]["p50"] == pytest.approx(30.0)
    assert lat["stage2"]["max"] == pytest.approx(2.0) and lat["air"]["max"] == pytest.approx(1.8)
    assert lat["stage3"]["p50"] == pytest.approx((106.5 + 86.2) / 2)
    assert sorted([lat["e2e"]["max"], lat["e2e"]["p50"] * 2 - lat["e2e"]["max"]]) == pytest.approx([130.0, 150.0])


def test_a_command_never_applied_has_no_e2e():
    lat = latency_metrics([record(0.9, 0.93, 0.932, 0.9335, 1.04, 200)], Applications([(9.0, 200)]))  # 8 s later
    assert lat["e2e"]["n"] == 0 and lat["e2e"]["p50"] is None and lat["stage3"]["n"] == 1


def test_a_superseded_command_takes_effect_with_the_newer_one_that_replaced_it():
    """The gateway applies the newest command due at a step: a command it superseded took effect with the newer
    one (which carries the plan forward), never with an older one or one from the counter's next lap."""
    applied = Applications([(1.00, 25), (1.02, 27), (1.04, 28), (6.12, 26)])
    assert applied.first(26, 1.005) == 1.02      # 26 superseded by 27, applied at 1.02
    assert applied.first(27, 1.005) == 1.02
    assert applied.first(28, 1.005) == 1.04      # 27 is older than 28: not it
    assert applied.first(255, 0.99) == 1.00     # counters wrap: 25 is newer than 255
    assert applied.first(140, 0.99) is None     # 25, 27, 28 are 'older' than 140 (more than half a lap ahead)
    assert applied.first(26, 1.05) is None      # 6.12 is beyond the window


def test_realtime_rows_are_matched_on_the_apps_clock():
    """can-applied.csv's t_clock (the run clock the apps stamp with) is the application time when present."""
    rows = [{"t": "1.00", "t_clock": "1.07", "event": "command", "counter": "3"},
            {"t": "1.01", "t_clock": "", "event": "command", "counter": "4"}]
    assert applied_times(rows) == Applications([(1.01, 4), (1.07, 3)])
    stamps = with_can_applied(record(0.9, 0.93, 0.932, 0.9335, 1.04, 3), applied_times(rows))
    assert stamps[v2x.CAN_APPLIED] == v2x.stamp_ns(1.07)


def test_pdr_and_inter_packet_gaps_per_link():
    events = [{"event": "v2x_sent", "t": 0.0, "from": "rsu"}]
    events += [{"event": "v2x_delivered", "t": 0.1 * k + 0.001, "from": "rsu", "to": "cav"} for k in range(8)]
    events += [{"event": "v2x_dropped", "t": 0.85, "from": "rsu", "to": "cav", "reason": "channel"},
               {"event": "v2x_dropped", "t": 0.95, "from": "rsu", "to": "ped", "reason": "out_of_range"}]
    pdr, ipg = link_metrics(events)
    assert pdr["rsu->cav"] == {"pdr": pytest.approx(8 / 9), "delivered": 8, "dropped": 1}
    assert pdr["rsu->ped"]["pdr"] == 0.0
    assert ipg["rsu->cav"]["n"] == 7 and ipg["rsu->cav"]["p50"] == pytest.approx(100.0)


def test_age_of_information_of_a_subject():
    # frames about ev taken every 0.1 s, arriving 0.05 s later; one lost (frame 0.3)
    events = [{"event": "v2x_delivered", "to": "cav", "subject": "ev", "t": f + 0.05, "frame_t": f}
              for f in (0.0, 0.1, 0.2, 0.4)]
    events.append({"event": "v2x_delivered", "to": "cav", "subject": "cav", "t": 0.5, "frame_t": 0.49})
    events.append({"event": "v2x_delivered", "to": "rsu", "subject": "ev", "t": 0.5, "frame_t": 0.49})
    got = subject_deliveries(events, "cav", "ev")
    assert got == [(0.05, 0.0), (0.15000000000000002, 0.1), (0.25, 0.2), (0.45, 0.4)]
    aoi = aoi_metrics(got, t_end=0.5, dt=0.01)
    # sampled every 10 ms from 0.05 s: the oldest sample is at 0.44 s, frame 0.2 is the freshest then
    assert aoi["n"] == 46 and aoi["max"] == pytest.approx(240.0) and aoi["p50"] == pytest.approx(100.0)
    assert aoi_metrics([], 1.0, 0.01)["n"] == 0


def test_torn_jsonl_lines_are_skipped(tmp_path):
    path = tmp_path / "x.jsonl"
    path.write_text(json.dumps({"a": 1}) + "\n" + '{"b": ' + "\n")
    assert read_jsonl(path) == [{"a": 1}]
    assert read_jsonl(tmp_path / "missing.jsonl") == []


def test_clock_bounds_are_half_each_apps_round_trip_in_simulated_ms():
    """Realtime: an app's stamps are on the master's clock to within half the round trip of its offset
    estimate; at RTF 0.3 one wall ms is 0.3 simulated ms. Lockstep stamps are simulated time: no bound."""
    members = {"rsu": {"clock_offset": {"offset_ns": 39_067, "rtt_ns": 449_365, "samples": 8}},
               "cav": {"clock_offset": {"offset_ns": 14_013, "rtt_ns": 352_346, "samples": 8}},
               "late": {"clock_offset": None}}  # joined without an estimate: nothing to say
    meta = {"mode": "realtime", "realtime": {"target_rtf": 0.3}, "participants": {"members": members}}
    bounds = clock_bounds(meta)
    assert list(bounds) == ["cav", "rsu"]
    assert bounds["rsu"] == pytest.approx(0.449365 / 2 * 0.3) and bounds["cav"] == pytest.approx(0.352346 / 2 * 0.3)
    assert clock_bounds({**meta, "mode": "lockstep"}) is None
