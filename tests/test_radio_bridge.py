"""The V2X air: channel decisions per receiver, arrival times, logs, and the [v2x] table's errors."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from fmus.channel.model import ChannelModel, ChannelParams
from master.links.radio_bridge import Air, Station, V2xSpec, parse_v2x
from master.world.los import line_of_sight
from master.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def _spec(positions: dict, mode="channel", **channel) -> V2xSpec:
    return V2xSpec(mode=mode, channel=channel,
                   stations={n: Station(n, position=tuple(p)) for n, p in positions.items()})


def _air(spec, obstruction=None):
    log = []
    air = Air(spec, lambda name, t: spec.stations[name].position, obstruction, log.append)
    return air, log


def test_close_stations_hear_each_other_with_the_models_latency():
    spec = _spec({"rsu": (0, 0, 5), "cav": (30, 0, 0), "ev": (0, 40, 0)})
    air, log = _air(spec)
    air.transmit("rsu", 0, 1.0, b"x" * 120)
    assert air.in_flight == 2
    assert air.due(1.0) == []  # nothing arrives at the instant it is sent
    got = air.due(1.1)
    assert sorted(d.receiver for d in got) == ["cav", "ev"]
    for d in got:
        assert d.sender == "rsu" and d.payload == b"x" * 120 and d.t_tx == 1.0
        assert 1.0 < d.arrival < 1.1
    assert got[0].arrival <= got[1].arrival
    events = [e["event"] for e in log]
    assert events.count("v2x_sent") == 1 and events.count("v2x_delivered") == 2
    # the air's latency is the transmitter's channel model's for that packet
    model = ChannelModel(ChannelParams(seed=air.models["rsu"].p.seed))
    ref = model.evaluate_one((0, 0, 5), (30, 0, 0), packet_bytes=120, seq=0, tx_id=air.ids["rsu"],
                             rx_id=air.ids["cav"])
    cav = next(d for d in got if d.receiver == "cav")
    assert cav.arrival - 1.0 == pytest.approx(ref["latency_s"])


def test_out_of_range_and_bypass_are_logged_not_delivered():
    spec = _spec({"a": (0, 0, 0), "b": (2000, 0, 0)})
    air, log = _air(spec)
    air.transmit("a", 3, 0.5, b"m")
    assert air.due(10.0) == [] and air.counts["out_of_range"] == 1
    assert log[-1]["reason"] == "out_of_range" and log[-1]["to"] == "b"
    air, log = _air(_spec({"a": (0, 0, 0), "b": (10, 0, 0)}, mode="bypass"))
    air.transmit("a", 0, 0.0, b"m")
    assert air.due(1.0) == [] and [e["event"] for e in log] == ["v2x_sent"]


def test_unknown_sender_is_rejected_with_the_reason():
    air, log = _air(_spec({"a": (0, 0, 0), "b": (10, 0, 0)}))
    air.transmit("mallory", 0, 0.0, b"m")
    assert air.counts["unknown_sender"] == 1 and air.counts["sent"] == 0
    assert "unknown station 'mallory'" in log[-1]["reason"]


def test_the_corner_building_blocks_the_link_it_stands_in():
    """Case-study geometry: the cav south of the junction and the ev west of it, building between."""
    world = load_scenario(ROOT / "scenarios" / "ima_world.toml").world
    spec = _spec({"cav": (1.75, -60.0, 0.0), "ev": (-60.0, -1.75, 0.0), "rsu": (6.5, 6.5, 6.0)},
                 wall_loss_db=30.0)
    air, log = _air(spec, lambda p, q: line_of_sight(p, q, world.buildings))
    for seq in range(50):
        air.transmit("ev", seq, 0.1 * seq, b"b" * 200)
    air.due(100.0)
    to_cav = [e for e in log if e.get("to") == "cav" and e["event"] in ("v2x_dropped", "v2x_scheduled")]
    to_rsu = [e for e in log if e.get("to") == "rsu" and e["event"] in ("v2x_dropped", "v2x_scheduled")]
    assert all(e["walls"] == 2 for e in to_cav) and all(e["walls"] == 0 for e in to_rsu)
    delivered_cav = sum(e["event"] == "v2x_scheduled" for e in to_cav)
    delivered_rsu = sum(e["event"] == "v2x_scheduled" for e in to_rsu)
    assert delivered_rsu == 50 and delivered_cav < 10


def test_delivery_ratio_follows_the_models_pdr():
    """Over many packets at one distance the delivered share matches the model's PDR.

    Shadowing is off: with fixed stations it is one draw for every packet, not an average.
    """
    d = 275.0
    spec = _spec({"a": (0, 0, 0), "b": (d, 0, 0)}, shadowing_sigma_db=0.0)
    air, log = _air(spec)
    n = 1500
    for seq in range(n):
        air.transmit("a", seq, seq * 0.1, b"p" * 190)
    delivered = len(air.due(1e9)) / n
    pdr = air.models["a"].evaluate((0, 0, 0), (d, 0, 0), packet_bytes=190).pdr
    assert 0.05 < float(pdr) < 0.95, "pick a distance in the transition region"
    assert delivered == pytest.approx(float(pdr), abs=0.04)


def test_decisions_are_reproducible():
    spec = _spec({"a": (0, 0, 0), "b": (275, 0, 0), "c": (0, 270, 0)}, shadowing_sigma_db=0.0)
    runs = []
    for _ in range(2):
        air, _ = _air(spec)
        for seq in range(100):
            air.transmit("a", seq, seq * 0.1, b"q" * 100)
        runs.append([(x.receiver, x.seq, x.arrival) for x in air.due(1e9)])
    assert runs[0] == runs[1] and 0 < len(runs[0]) < 200


def _problems(table, instances=None):
    out = []
    spec = parse_v2x(table, instances or {}, lambda k, m: out.append((k, m)))
    return spec, out


def test_parse_v2x_names_the_offending_key():
    spec, probs = _problems({"stations": {"rsu": {"position": [0, 0, 5]}, "x": {"position": [1, 2, 3]}}})
    assert probs == [] and spec.stations["rsu"].position == (0.0, 0.0, 5.0)
    cases = [
        ({"mode": "air", "stations": {"a": {"position": [0, 0, 0]}}}, "v2x.mode"),
        ({"colour": 1, "stations": {"a": {"position": [0, 0, 0]}}}, "v2x.colour"),
        ({"stations": {}}, "v2x.stations"),
        ({"stations": {"a": {"position": [0, 0]}}}, "v2x.stations.a.position"),
        ({"stations": {"a": {"position": [0, 0, 0], "vehicle": "cav"}}}, "v2x.stations.a"),
        ({"stations": {"a": {"vehicle": "ghost"}}}, "v2x.stations.a.vehicle"),
        ({"stations": {"a": {"position": [0, 0, 0], "height": 2}}}, "v2x.stations.a.height"),
        ({"channel": {"tx_powr_dbm": 20}, "stations": {"a": {"position": [0, 0, 0]}}}, "v2x.channel.tx_powr_dbm"),
        ({"channel": {"technology": "wifi"}, "stations": {"a": {"position": [0, 0, 0]}}}, "v2x.channel"),
        ({"max_range_m": -1, "stations": {"a": {"position": [0, 0, 0]}}}, "v2x.max_range_m"),
    ]
    for table, key in cases:
        spec, probs = _problems(table)
        assert spec is None and key in [k for k, _ in probs], (table, probs)


def test_resolved_round_trips_through_the_parser():
    spec, _ = _problems({"mode": "bypass", "max_range_m": 300.0, "channel": {"tx_power_dbm": 20.0},
                         "stations": {"rsu": {"position": [1.0, 2.0, 3.0]}}})
    again, probs = _problems(spec.resolved())
    assert probs == [] and again == spec
    assert math.isclose(again.max_range_m, 300.0)
