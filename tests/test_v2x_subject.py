"""The air ties each frame to the world vehicle it describes (subject, frame_t), for the age of information."""
from __future__ import annotations

import json
import math
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import pytest

from bridges.geo import GeoOrigin
from bridges.j2735.bsm import EmergencyInfo, surrogate_bsm
from bridges.j2735.spat import IntersectionSignals, Movement, Spat
from bridges.security import PSID_SPAT_MAP, PSID_SURROGATE_BSM, ScenarioCA, Signer, time64_us
from bridges.security.oer import unsecured
from bridges.v2x import FRAME, SEND, stamp_ns
from master.run.metrics import run_metrics
from master.links.radio_bridge import Air, RadioBridge, Station, V2xSpec
from master.links.v2x_subject import (BEYOND_GATE, NOT_A_BSM, SubjectFinder, UNKNOWN_BODY_EXTRA_M, nearest,
                                unwrap, world_bodies)
from master.world.layout import VehicleSpec, WorldLayout

NOW = datetime(2026, 6, 1, 12, 0, tzinfo=timezone.utc)
ORIGIN = GeoOrigin(48.1374, 11.5755, 520.0)  # not the default: the world's own origin must be used
EV = VehicleSpec("ev", length=6.5, width=2.3, height=2.6, kind="emergency", rear_overhang=1.42)  # centre 1.83 ahead
CAV = VehicleSpec("cav", length=4.5, width=1.8, height=1.5)  # default overhang 0.95: centre 1.30 ahead


@pytest.fixture(scope="module")
def signer():
    ca = ScenarioCA.create(start=NOW - timedelta(days=1))
    return Signer(ca.issue("rsu", [PSID_SURROGATE_BSM, PSID_SPAT_MAP], start=NOW - timedelta(days=1)))


def _bsm(x: float, y: float, track: int = 1, emergency: bool = False, origin: GeoOrigin = ORIGIN) -> bytes:
    lat, lon, h = origin.to_geodetic(x, y, 0.0)
    return surrogate_bsm(track, b"salt", msg_count=1, sec_mark_ms=100, latitude=float(lat), longitude=float(lon),
                         elevation=float(h), speed=10.0, heading=90.0, width=2.0, length=5.0,
                         emergency=EmergencyInfo(response_type="emergency") if emergency else None).encode()


def _signed(signer, payload: bytes, psid: int = PSID_SURROGATE_BSM) -> bytes:
    return signer.sign(payload, psid, time64_us(NOW.timestamp()))


def _spat() -> bytes:
    return Spat([IntersectionSignals(7, movements=[Movement(2, "protected-Movement-Allowed")])]).encode()


class FakeVehicle:
    """A VehicleDynamics-like FMU: x, y (rear axle), yaw, v outputs at constant speed; `time` its state time."""

    def __init__(self, x, y, yaw, v):
        self.x0, self.y0, self.yaw, self.v, self.time = x, y, yaw, v, 0.0
        names = ("x", "y", "yaw", "v", "a")
        self.variables = {n: SimpleNamespace(valueReference=i, causality="output") for i, n in enumerate(names)}

    def state(self, t):
        return (self.x0 + self.v * t * math.cos(self.yaw), self.y0 + self.v * t * math.sin(self.yaw))

    def centre(self, spec, t):
        x, y = self.state(t)
        return x + spec.centre_offset * math.cos(self.yaw), y + spec.centre_offset * math.sin(self.yaw)

    def access_key(self, name):
        return "Real"

    def accessor(self, key, vrs, setter):
        assert not setter
        return lambda: [[*self.state(self.time), self.yaw, self.v, 0.0][i] for i in vrs]


def _vehicles():
    # the case study's geometry: ev eastbound from the west, cav northbound from the south
    return {"ev": FakeVehicle(-60.0, -1.75, 0.0, 16.667), "cav": FakeVehicle(1.75, -50.0, math.pi / 2, 8.333)}


def _layout():
    return WorldLayout(vehicles={"ev": EV, "cav": CAV}, origin=ORIGIN)


# -- the pure parts -------------------------------------------------------------------------------------
def test_unwrap_takes_signed_and_unsecured_envelopes_and_nothing_else(signer):
    bsm = _bsm(0.0, 0.0)
    assert unwrap(_signed(signer, bsm)) == bsm
    assert unwrap(unsecured(bsm)) == bsm
    for junk in (bsm, b"", b"\x03", b"\x03" + b"\xff" * 40, b"garbage", None, 42):
        assert unwrap(junk) is None


def test_nearest_respects_each_gate():
    centres = [("a", 0.0, 0.0, 5.0), ("b", 6.0, 0.0, 5.0)]
    assert nearest((2.0, 0.0), centres) == ("a", 2.0)
    assert nearest((4.0, 0.0), centres)[0] == "b"
    assert nearest((0.0, 5.5), centres) == (None, math.inf)


def test_finder_uses_the_body_centre_not_the_rear_axle(signer):
    fmus = _vehicles()
    finder = SubjectFinder(ORIGIN, world_bodies(fmus, _layout()), gate_m=5.0)
    ev_c = fmus["ev"].centre(EV, 0.0)  # (-58.17, -1.75); rear axle (-60, -1.75)
    # 4.5 m ahead of the centre: 6.33 m from the rear axle, still the ev
    assert finder.find(_signed(signer, _bsm(ev_c[0] + 4.5, ev_c[1])), 0.0)[0] == "ev"
    # 4.5 m behind the rear axle: 6.33 m from the centre, nobody
    assert finder.find(_signed(signer, _bsm(-64.5, -1.75)), 0.0)[:2] == (None, BEYOND_GATE)
    # the vehicle is moved back to the frame's time: the state is 0.5 s later (8.3 m further east)
    fmus["ev"].time = 0.5
    assert finder.find(_signed(signer, _bsm(*ev_c)), 0.0)[0] == "ev"
    assert finder.find(_signed(signer, _bsm(*ev_c)), 0.5)[0] is None


def test_without_a_layout_every_xy_fmu_counts_with_a_wider_gate(signer):
    fmus = _vehicles()
    fmus["tl"] = SimpleNamespace(variables={"state_2": SimpleNamespace(valueReference=0, causality="output")})
    bodies = world_bodies(fmus, None)
    assert sorted(b.name for b in bodies) == ["cav", "ev"]
    finder = SubjectFinder(ORIGIN, bodies, gate_m=5.0)
    # rear axle is the reference; the gate is 5 + UNKNOWN_BODY_EXTRA_M
    assert finder.find(_signed(signer, _bsm(-60.0 + 5.0 + UNKNOWN_BODY_EXTRA_M - 0.2, -1.75)), 0.0)[0] == "ev"
    assert finder.find(_signed(signer, _bsm(-60.0 + 5.0 + UNKNOWN_BODY_EXTRA_M + 0.2, -1.75)), 0.0)[0] is None


def test_air_carries_the_extra_fields_on_every_event_of_the_frame():
    spec = V2xSpec(stations={"rsu": Station("rsu", position=(0, 0, 5)), "cav": Station("cav", position=(30, 0, 0)),
                             "far": Station("far", position=(5000, 0, 0))})
    log = []
    air = Air(spec, lambda n, t: spec.stations[n].position, None, log.append)
    air.transmit("rsu", 0, 1.0, b"x" * 100, about={"subject": "ev", "frame_t": 0.9, "t": -1})
    got = air.due(2.0)
    assert [d.about for d in got] == [{"subject": "ev", "frame_t": 0.9, "t": -1}]
    kinds = {e["event"] for e in log}
    assert kinds == {"v2x_sent", "v2x_dropped", "v2x_scheduled", "v2x_delivered"}
    for e in log:
        assert e["subject"] == "ev" and e["frame_t"] == 0.9 and e["t"] >= 1.0  # the event's own t wins
    air.transmit("rsu", 1, 3.0, b"x")  # without: no extra fields
    assert all("subject" not in e for e in log[len(kinds):])


# -- in the hook ----------------------------------------------------------------------------------------
class FakeBus:
    def __init__(self):
        self.published = []

    def subscribe(self, key, callback=None):
        return SimpleNamespace(close=lambda: None)

    def publish(self, key, payload, t_sim, stamps=None):
        self.published.append((key, payload, t_sim, dict(stamps or {})))


def _run(frames, fmus, stop: float, step: float = 0.01, layout=None, mode="channel"):
    """Drive a RadioBridge like the master's loop: frames are (t_send, payload, frame_t or None)."""
    spec = V2xSpec(mode=mode, max_range_m=500.0,
                   stations={"rsu": Station("rsu", position=(6.5, 6.5, 6.0)), "cav": Station("cav", vehicle="cav")})
    log = []
    ctx = SimpleNamespace(bus=FakeBus(), events=log.append, fmus=fmus, t0=0.0, world=None, stamp_time=lambda t: t,
                          scenario=SimpleNamespace(world=layout or _layout()))
    hook = RadioBridge(spec)
    hook.open(ctx)
    pending = sorted(frames, key=lambda f: f[0])
    n = int(round(stop / step))
    for k in range(n):
        t_next = (k + 1) * step
        for fmu in fmus.values():
            fmu.time = t_next
        while pending and pending[0][0] <= t_next + 1e-12:
            t_send, payload, frame_t = pending.pop(0)
            stamps = {SEND: stamp_ns(t_send)}
            if frame_t is not None:
                stamps[FRAME] = stamp_ns(frame_t)
            hook._on_tx(SimpleNamespace(key="v2x/tx/rsu", t_sim=t_send, sender="rsu", seq=k, payload=payload,
                                        stamps=stamps))
        hook.after_step(k, t_next)
    return hook.close(), log


def test_frames_are_tied_to_the_vehicle_they_describe(signer):
    fmus = _vehicles()
    t_ev, t_cav, t_far, t_spat, t_junk, t_bare = 0.105, 0.205, 0.305, 0.405, 0.505, 0.605
    ev = fmus["ev"].centre(EV, t_ev)
    cav = fmus["cav"].centre(CAV, t_cav)
    frames = [
        (t_ev, _signed(signer, _bsm(ev[0] + 1.0, ev[1] - 0.8, track=1, emergency=True)), 0.04),
        (t_cav, _signed(signer, _bsm(cav[0] - 0.5, cav[1] + 1.2, track=2)), 0.15),
        (t_far, _signed(signer, _bsm(-20.0, -60.0, track=3)), 0.25),  # inside the building: no vehicle there
        (t_spat, _signed(signer, _spat(), PSID_SPAT_MAP), None),
        (t_junk, b"\x03garbage\x00\xff" * 9, 0.45),
        (t_bare, _bsm(*fmus["ev"].centre(EV, t_bare)), 0.55),  # a BSM not in an envelope
    ]
    section, log = _run(frames, fmus, stop=1.0)
    delivered = {round(e["t_tx"], 3): e for e in log if e["event"] == "v2x_delivered"}
    assert set(delivered) == {t_ev, t_cav, t_far, t_spat, t_junk, t_bare}  # 57 m, clear sky: all arrive
    expect = {t_ev: ("ev", 0.04), t_cav: ("cav", 0.15), t_far: (None, 0.25), t_spat: (None, None),
              t_junk: (None, 0.45), t_bare: (None, 0.55)}
    for t, (subject, frame_t) in expect.items():
        for e in log:
            if e.get("seq") is not None and e["event"] in ("v2x_sent", "v2x_scheduled", "v2x_delivered") \
                    and round(e.get("t_tx", e["t"]), 3) == t:
                assert e["subject"] == subject and e["frame_t"] == frame_t, e
    assert delivered[t_ev]["frame_t"] == pytest.approx(0.04, abs=1e-9)
    assert section["subjects"] == {"cav": 1, "ev": 1}
    assert section["untied"] == {BEYOND_GATE: 1, NOT_A_BSM: 3}
    assert section["subject_cost_us"]["n"] == 6 and section["sent"] == 6
    json.dumps(log)  # the events go to events.jsonl


def test_bypass_mode_ties_the_sent_event(signer):
    fmus = _vehicles()
    frames = [(0.05, _signed(signer, _bsm(*fmus["ev"].centre(EV, 0.05))), 0.01)]
    section, log = _run(frames, fmus, stop=0.1, mode="bypass")
    assert [(e["event"], e["subject"], e["frame_t"]) for e in log] == [("v2x_sent", "ev", 0.01)]


def test_age_of_information_of_the_ev_at_the_cav(signer, tmp_path):
    """10 Hz surrogate BSMs of the ev (camera frame 60 ms before the send) and of the cav; run_metrics
    gives cav<-ev ages between (arrival - frame_t) and that plus one period."""
    fmus = _vehicles()
    frames = []
    for k in range(20):
        t_send = 0.1 * k + 0.065
        frames.append((t_send, _signed(signer, _bsm(*fmus["ev"].centre(EV, t_send), track=1, emergency=True)),
                       t_send - 0.06))
        frames.append((t_send + 0.002, _signed(signer, _bsm(*fmus["cav"].centre(CAV, t_send + 0.002), track=2)),
                       t_send - 0.06))
    section, log = _run(frames, fmus, stop=2.2)
    assert section["subjects"] == {"cav": 20, "ev": 20}
    (tmp_path / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in log))
    metrics = run_metrics(tmp_path, {"sim_time_reached_s": 2.0})  # within a period of the last arrival
    aoi = metrics["aoi_ms"]["cav<-ev"]
    ev_rx = [e for e in log if e["event"] == "v2x_delivered" and e["subject"] == "ev"]
    assert len(ev_rx) == 20 and aoi["n"] > 150
    ages = [(e["t"] - e["frame_t"]) * 1e3 for e in ev_rx]
    assert all(60.0 < a < 70.0 for a in ages)  # 60 ms to the send, then the air's latency
    assert min(ages) - 1e-6 <= aoi["p50"] <= max(ages) + 100.0 + 1e-6
    assert aoi["max"] == pytest.approx(max(ages) + 100.0, abs=11.0)  # one period (sampled every 10 ms)
    assert set(metrics["aoi_ms"]) == {"cav<-cav", "cav<-ev"}  # the RSU also tells the cav about itself


def test_the_cost_per_frame_is_small(signer):
    """Decoding once per frame on the air (not per receiver): well under a millisecond."""
    fmus = _vehicles()
    finder = SubjectFinder(ORIGIN, world_bodies(fmus, _layout()))
    frame = _signed(signer, _bsm(*fmus["ev"].centre(EV, 0.0)))
    for _ in range(200):
        assert finder.about(frame, 0.0, 0.0)["subject"] == "ev"
    assert finder.section()["subject_cost_us"]["p50"] < 2000.0  # measured ~0.1-0.2 ms; loose for a busy CI
