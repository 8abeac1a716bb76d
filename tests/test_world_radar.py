"""The roadside radar: [world.radars.NAME] parsing, the detection and noise model, and its scans in the loop."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bridges import radar_stream
from master.world.layout import Building, RadarSpec, VehicleSpec, WorldLayout, parse_world
from master.world.los import line_of_sight
from master.world.radar import Radar, Target, targets

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml"
SW_CORNER = Building("sw_corner", -30.0, -30.0, 48.0, 48.0, 15.0)  # as in scenarios/ima_world.toml
WEST = {"position": [6.5, 6.5, 6.0], "heading_deg": 180.0}


def parse(radars: dict, buildings: list | None = None):
    """parse_world on a [world] table with these radars; (layout or None, problems as 'key: reason')."""
    problems: list[str] = []
    table = {"radars": radars}
    if buildings is not None:
        table["buildings"] = buildings
    layout = parse_world(table, {}, lambda key, reason: problems.append(f"{key}: {reason}"))
    return layout, problems


# -- [world.radars.NAME] -------------------------------------------------------------------------

def test_good_radar_table_with_defaults():
    layout, problems = parse({"west": dict(WEST, fov_deg=12.0, seed=7)})
    assert problems == []
    assert layout.radars == {"west": RadarSpec("west", (6.5, 6.5, 6.0), 180.0, fov_deg=12.0, seed=7)}
    r = layout.radars["west"]
    assert (r.min_range_m, r.max_range_m, r.rate_hz, r.p_detect) == (5.0, 250.0, 20.0, 0.98)
    assert (r.sigma_range_m, r.sigma_azimuth_deg, r.sigma_speed) == (0.25, 0.25, 0.1)
    assert parse({})[0].radars == {}


BAD = [
    ({"heading_deg": 180.0}, "world.radars.west.position: required"),
    ({"position": [1.0, 2.0], "heading_deg": 0.0}, "world.radars.west.position: expected [x, y, z]"),
    ({"position": [1.0, "a", 2.0], "heading_deg": 0.0}, "world.radars.west.position: expected [x, y, z]"),
    ({"position": [1.0, 1.0, -2.0], "heading_deg": 0.0}, "world.radars.west.position: z must be >= 0"),
    ({"position": [500.0, 1.0, 2.0], "heading_deg": 0.0}, "world.radars.west.position: outside the map"),
    ({"position": [-30.0, -30.0, 6.0], "heading_deg": 0.0}, "world.radars.west.position: inside building"),
    ({"position": [1.0, 1.0, 2.0]}, "world.radars.west.heading_deg: required"),
    (dict(WEST, heading_deg="west"), "world.radars.west.heading_deg: expected a finite number"),
    (dict(WEST, fov_deg=0.0), "world.radars.west.fov_deg: must be in (0, 360]"),
    (dict(WEST, fov_deg=361.0), "world.radars.west.fov_deg: must be in (0, 360]"),
    (dict(WEST, min_range_m=0.0), "world.radars.west.min_range_m: must be > 0"),
    (dict(WEST, max_range_m=-1.0), "world.radars.west.max_range_m: must be > 0"),
    (dict(WEST, min_range_m=50.0, max_range_m=40.0), "world.radars.west.max_range_m: must exceed min_range_m"),
    (dict(WEST, rate_hz=0.0), "world.radars.west.rate_hz: must be > 0"),
    (dict(WEST, sigma_range_m=0.0), "world.radars.west.sigma_range_m: must be > 0"),
    (dict(WEST, sigma_azimuth_deg=-0.1), "world.radars.west.sigma_azimuth_deg: must be > 0"),
    (dict(WEST, sigma_speed=0.0), "world.radars.west.sigma_speed: must be > 0"),
    (dict(WEST, p_detect=0.0), "world.radars.west.p_detect: must be in (0, 1]"),
    (dict(WEST, p_detect=1.5), "world.radars.west.p_detect: must be in (0, 1]"),
    (dict(WEST, seed=1.5), "world.radars.west.seed: expected an integer"),
    (dict(WEST, seed=-1), "world.radars.west.seed: must be >= 0"),
    (dict(WEST, fov=16.0), "world.radars.west.fov: unknown key (expected one of: position, heading_deg, fov_deg"),
    (dict(WEST, max_range=100.0), "world.radars.west.max_range: unknown key"),
    ("not a table", "world.radars.west: expected a table"),
]


@pytest.mark.parametrize("table,expected", BAD, ids=[e for _, e in BAD])
def test_bad_radar_rejected_with_key(table, expected):
    layout, problems = parse({"west": table}, buildings=[dataclasses.asdict(SW_CORNER)])
    assert layout is None
    assert any(p.startswith(expected) for p in problems), problems


def test_unknown_radar_key_says_did_you_mean():
    _, problems = parse({"west": dict(WEST, sigma_azimuth=0.5, p_detection=0.9)})
    assert any(p.startswith("world.radars.west.sigma_azimuth: unknown key") and "did you mean 'sigma_azimuth_deg'" in p
               for p in problems), problems
    assert any(p.startswith("world.radars.west.p_detection: unknown key") and "did you mean 'p_detect'" in p
               for p in problems), problems


def test_radars_must_be_a_table_of_tables_with_bus_safe_names():
    _, problems = parse([WEST])
    assert any(p.startswith("world.radars: expected a table of [world.radars.NAME] tables") for p in problems)
    _, problems = parse({"west/1": WEST})
    assert any(p.startswith("world.radars.west/1: name 'west/1' must be") for p in problems), problems
    _, problems = parse({"west": WEST}, buildings=[])
    assert problems == []
    problems = []
    parse_world({"radar": {"west": WEST}}, {}, lambda k, r: problems.append(f"{k}: {r}"))
    assert any(p.startswith("world: unknown key 'radar'") and "did you mean 'radars'" in p for p in problems)


def test_shipped_world_has_the_west_radar_and_resolves_again(tmp_path):
    import tomli_w

    from master.run.recorder import _toml_safe
    from master.scenario.loader import load_scenario

    sc = load_scenario(SCENARIO)
    west = sc.world.radars["west"]
    assert (west.position, west.heading_deg, west.fov_deg, west.max_range_m, west.rate_hz) == \
        ((6.5, 6.5, 6.0), 180.0, 16.0, 250.0, 20.0)
    path = tmp_path / "resolved.toml"
    path.write_text(tomli_w.dumps(_toml_safe(sc.resolved())))
    assert load_scenario(path).world.radars == sc.world.radars
    # a world without radars resolves without the key, as before radars existed
    assert "radars" not in WorldLayout().resolved()


# -- the radar model -------------------------------------------------------------------------------

def radar(buildings=(), **spec) -> Radar:
    """The shipped west radar (on the camera pole, looking west) with `spec` changed."""
    s = dataclasses.replace(RadarSpec("west", (6.5, 6.5, 6.0), 180.0), **spec)
    return Radar(s, lambda p, q: not line_of_sight(p, q, buildings)[0])


def truth(r: Radar, v: Target) -> tuple[float, float, float]:
    """(slant range, azimuth from boresight, radial speed) of `v` from radar `r`, noise-free."""
    px, py, pz = r.position
    d = np.array([v.x - px, v.y - py, v.z - pz])
    rng = float(np.linalg.norm(d))
    az = (math.atan2(d[1], d[0]) - r.heading + math.pi) % (2 * math.pi) - math.pi
    return rng, az, v.speed * (math.cos(v.heading) * d[0] + math.sin(v.heading) * d[1]) / rng


EV = Target(-100.0, -1.75, 1.3, 16.7, 0.0)  # on the eastbound lane, 107 m west of the pole, coming east


def test_vehicle_in_the_beam_reported_at_its_range_and_azimuth():
    r = radar()
    scan = r.scan(0.5, {"ev": EV})
    assert (scan.radar, scan.scan_id, scan.t, scan.position) == ("west", 0, 0.5, (6.5, 6.5, 6.0))
    assert scan.heading == pytest.approx(math.pi) and scan.fov == pytest.approx(math.radians(16.0))
    assert scan.sigma_azimuth == pytest.approx(math.radians(0.25))
    assert len(scan.objects) == 1 and r.reported == ["ev"]
    rng, az, vr = truth(r, EV)
    assert rng == pytest.approx(math.sqrt(106.5 ** 2 + 8.25 ** 2 + 4.7 ** 2))
    assert az > 0  # south of the boresight (west) is counter-clockwise from it
    o = scan.objects[0]
    assert abs(o.range_m - rng) < 5 * 0.25
    assert abs(o.azimuth - az) < 5 * math.radians(0.25)
    assert abs(o.radial_speed - vr) < 5 * 0.1
    # over many scans the noise has the stated sigmas about the truth
    objs = np.array([[o.range_m, o.azimuth, o.radial_speed] for _ in range(4000)
                     for o in r.scan(1.0, {"ev": EV}).objects])
    assert len(objs) > 3800  # p_detect 0.98
    err = objs - np.array([rng, az, vr])
    sig = np.array([0.25, math.radians(0.25), 0.1])
    assert np.all(np.abs(err.mean(axis=0)) < 4 * sig / math.sqrt(len(objs)))
    assert np.allclose(err.std(axis=0), sig, rtol=0.05)
    # and the scan goes on the wire as bridges.radar_stream states it, placing the ev near its lane
    back = radar_stream.decode_scan(radar_stream.encode_scan(scan))
    assert back == scan
    gx, gy = back.ground_point(back.objects[0])
    assert gx == pytest.approx(EV.x, abs=1.5) and gy == pytest.approx(EV.y, abs=1.5)


@pytest.mark.parametrize("where,why", [
    (Target(-100.0, -20.0, 1.3, 10.0, 0.0), "off the boresight by 14 deg: outside the 16 deg beam"),
    (Target(6.5, 80.0, 1.3, 10.0, 0.0), "north of the pole: 90 deg off the boresight"),
    (Target(-250.0, 6.5, 1.3, 10.0, 0.0), "on the boresight, 256 m away: beyond max_range_m"),
    (Target(4.5, 6.5, 4.0, 10.0, 0.0), "on the boresight 2.8 m away: inside min_range_m"),
])
def test_outside_the_coverage_not_reported(where, why):
    r = radar(p_detect=1.0)
    assert r.scan(0.0, {"v": where}).objects == [], why
    assert r.scan(0.0, {"v": dataclasses.replace(where, x=-100.0, y=1.0)}).objects != []  # the same, in the beam


def test_building_hides_a_vehicle_other_vehicles_do_not():
    """Looking south-west across the sw_corner building: the vehicle behind it is not reported, while a
    vehicle right in front of another one leaves it reported (no occlusion by vehicles)."""
    behind = Target(-60.0, -60.0, 1.3, 10.0, math.radians(45))
    ahead = Target(-20.0, 1.0, 1.3, 10.0, 0.0)
    in_line = Target(-39.875, -3.125, 1.3, 10.0, 0.0)  # the pole, `ahead` and it on one line (xy)
    assert len(radar(heading_deg=225.0, p_detect=1.0).scan(0.0, {"v": behind}).objects) == 1  # no building
    r = radar([SW_CORNER], heading_deg=225.0, p_detect=1.0)
    assert r.scan(0.0, {"v": behind}).objects == []
    r = radar([SW_CORNER], heading_deg=200.0, fov_deg=40.0, p_detect=1.0)
    scan = r.scan(0.0, {"z_ahead": ahead, "a_in_line": in_line})
    assert r.reported == ["z_ahead", "a_in_line"]  # sorted by range, nearer first (not by name)
    assert scan.objects[0].range_m < scan.objects[1].range_m


def test_radial_speed_negative_approaching_positive_receding():
    r = radar(p_detect=1.0, sigma_speed=0.01)
    coming = r.scan(0.0, {"ev": EV}).objects[0].radial_speed
    going = r.scan(0.0, {"ev": dataclasses.replace(EV, heading=math.pi)}).objects[0].radial_speed
    assert coming < -16.0 and going > 16.0  # nearly along the line of sight: |v_r| close to 16.7
    crossing = Target(-100.0, -1.75, 1.3, 16.7, math.pi / 2)  # northbound: across the line of sight
    assert abs(r.scan(0.0, {"v": crossing}).objects[0].radial_speed) < 16.7 * 0.1
    stopped = r.scan(0.0, {"ev": dataclasses.replace(EV, speed=0.0)}).objects[0].radial_speed
    assert abs(stopped) < 5 * 0.01


def test_same_seed_same_scans_another_seed_other_noise():
    fleet = {"ev": EV, "b": Target(-150.0, -1.75, 1.3, 14.0, 0.0), "c": Target(-60.0, 1.75, 1.3, 12.0, math.pi)}
    a, b, c = radar(seed=5), radar(seed=5), radar(seed=6)
    sa = [a.scan(k * 0.05, fleet) for k in range(50)]
    sb = [b.scan(k * 0.05, fleet) for k in range(50)]
    sc = [c.scan(k * 0.05, fleet) for k in range(50)]
    assert sa == sb and [s.scan_id for s in sa] == list(range(50))
    assert sa != sc
    assert len(a.scan_times) == 50 and all(dt >= 0 for dt in a.scan_times)


def test_a_vehicle_entering_the_beam_does_not_shift_another_ones_noise():
    """Each vehicle draws the same variates every scan, covered or not (here: out of range, then in the beam)."""
    out = Target(-300.0, 6.5, 1.3, 10.0, 0.0)  # on the boresight, beyond max_range_m
    r1, r2 = radar(seed=3, p_detect=1.0), radar(seed=3, p_detect=1.0)
    for k in range(20):
        s1 = r1.scan(k * 0.05, {"a": out, "ev": EV})
        s2 = r2.scan(k * 0.05, {"a": dataclasses.replace(out, x=-100.0, y=2.0), "ev": EV})
        assert len(s1.objects) == 1 and len(s2.objects) == 2
        assert s1.objects[0] == s2.objects[r2.reported.index("ev")]


@pytest.mark.parametrize("p", [0.3, 0.7, 1.0])
def test_p_detect_is_the_fraction_of_scans_reported(p):
    r = radar(p_detect=p, seed=11)
    n = 4000
    hits = sum(len(r.scan(k * 0.05, {"ev": EV}).objects) for k in range(n))
    assert abs(hits / n - p) <= 4 * math.sqrt(p * (1 - p) / n) + 1e-12


def test_targets_from_rear_axle_poses():
    ev = VehicleSpec("ev", length=6.5, height=2.6, rear_overhang=1.42)  # centre 1.83 m ahead of the rear axle
    t = targets({"ev": (-116.0, -1.75, math.pi / 2, 16.7)}, {"ev": ev})["ev"]
    assert (t.x, t.y, t.z, t.speed, t.heading) == pytest.approx((-116.0, -1.75 + 1.83, 1.3, 16.7, math.pi / 2))


# -- in the master's loop ------------------------------------------------------------------------------

class FakeVehicle:
    """Just enough of a master.fmi FMU for WorldParticipant.attach: outputs x, y, yaw, v read by accessor."""

    def __init__(self, x: float, y: float, yaw: float, v: float):
        self.values = {"x": x, "y": y, "yaw": yaw, "v": v}
        self.variables = {n: SimpleNamespace(valueReference=i) for i, n in enumerate(self.values)}

    def access_key(self, name: str) -> str:
        return "Real"

    def accessor(self, key, vrs, setter):
        names = list(self.values)
        return lambda: [self.values[names[vr]] for vr in vrs]


def test_world_participant_scans_the_radar_at_its_rate_and_publishes_it():
    pytest.importorskip("pybullet")
    from master.links.streams import SensorStreams
    from master.world.world import WorldParticipant

    layout = WorldLayout(buildings=[SW_CORNER],
                         vehicles={"ev": VehicleSpec("ev", kind="emergency", length=6.5, height=2.6,
                                                     rear_overhang=1.42),
                                   "cav": VehicleSpec("cav")},
                         radars={"west": RadarSpec("west", (6.5, 6.5, 6.0), 180.0, p_detect=1.0)})
    fmus = {"ev": FakeVehicle(-116.0, -1.75, 0.0, 16.7), "cav": FakeVehicle(1.75, -45.0, math.pi / 2, 8.3)}
    published = []
    bus = SimpleNamespace(publish=lambda key, payload, t: published.append((key, payload, t)))
    streams = SensorStreams(bus, camera_encoding="off")
    part = WorldParticipant(layout, start=0.0)
    got = []
    part.listeners += [lambda kind, name, t, data: got.append((kind, name, t, data)), streams]
    part.attach(fmus, 0.0)
    try:
        for k in range(1, 101):  # 1 s in 0.01 s steps; the ev drives east, the cav waits south of the junction
            t = k * 0.01
            fmus["ev"].values["x"] = -116.0 + 16.7 * t
            part.after_step(k - 1, t)
        meta = part.metadata()["radars"]["west"]
    finally:
        part.close()
    scans = [(t, data) for kind, name, t, data in got if kind == "radar"]
    assert [name for kind, name, _, _ in got if kind == "radar"] == ["west"] * 21
    assert [t for t, _ in scans] == pytest.approx([k * 0.05 for k in range(21)])  # 20 Hz from t0
    assert [s.scan_id for _, s in scans] == list(range(21))
    assert all(len(s.objects) == 1 and s.objects[0].radial_speed < -15.0 for _, s in scans)  # the ev only
    assert meta["scans"] == 21 and meta["rate_hz"] == 20.0 and meta["objects_reported"] == 21
    assert meta["scan_s"]["n"] == 21
    assert meta["vehicles"]["ev"] == {"first_report_s": 0.0, "last_report_s": pytest.approx(1.0), "scans_reported": 21}
    assert meta["vehicles"]["cav"] == {"first_report_s": None, "last_report_s": None, "scans_reported": 0}
    # published on radar/west, stamped with the scan's time, decodable as the scan
    radar_msgs = [(key, payload, t) for key, payload, t in published if key.startswith("radar/")]
    assert len(radar_msgs) == 21 and streams.counts["radar"] == 21
    key, payload, t = radar_msgs[3]
    assert key == radar_stream.KEY.format("west") and t == pytest.approx(0.15)
    assert radar_stream.decode_scan(payload) == scans[3][1]


def test_no_radar_scans_without_sensors():
    pytest.importorskip("pybullet")
    from master.world.world import WorldParticipant

    layout = WorldLayout(vehicles={"ev": VehicleSpec("ev")},
                         radars={"west": RadarSpec("west", (6.5, 6.5, 6.0), 180.0)})
    part = WorldParticipant(layout, start=0.0, sensors=False)
    got = []
    part.listeners.append(lambda *a: got.append(a))
    part.attach({"ev": FakeVehicle(-100.0, -1.75, 0.0, 10.0)}, 0.0)
    try:
        for k in range(1, 11):
            part.after_step(k - 1, k * 0.01)
        assert got == [] and part.metadata()["radars"]["west"]["scans"] == 0
    finally:
        part.close()
