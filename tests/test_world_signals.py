"""Traffic-light heads: validated from [[world.signals]], lamps follow the controller's state_k.

The co-simulation test runs the TrafficLightController FMU on a short fixed-time
plan (20 s cycle: phases 2+6 then 4+8, each 5.5 s green, 3.3 s yellow, 1.2 s red
clearance) with a head for group 2 and one for group 4, and checks at every step
that the lamp colours in pybullet equal the colours for the state the run
recorded in timeseries.csv, and that rendered camera pixels show the lit lamp.
"""
from __future__ import annotations

import csv

import numpy as np
import pytest

pytest.importorskip("pybullet")

import pybullet as pb  # noqa: E402

from master.errors import ScenarioError  # noqa: E402
from master.scenario.loader import load_scenario  # noqa: E402
from master.world import signals  # noqa: E402
from master.world.layout import CameraSpec, SignalSpec, WorldLayout  # noqa: E402
from master.world.world import World  # noqa: E402

PLAN = """
[time]
stop = 20.0
step = 0.1
[fmus.tlc]
fmu = "{tlc}"
[fmus.tlc.parameters]
cycle = 20.0
split_1 = 0.0
split_2 = 10.0
split_3 = 0.0
split_4 = 10.0
split_5 = 0.0
split_6 = 10.0
split_7 = 0.0
split_8 = 10.0
yellow_2 = 3.3
yellow_4 = 3.3
yellow_6 = 3.3
yellow_8 = 3.3
red_clear_2 = 1.2
red_clear_4 = 1.2
red_clear_6 = 1.2
red_clear_8 = 1.2
[record]
variables = ["tlc.state_2", "tlc.state_4"]
[world.intersection]
arm_length = 60.0
"""
# two heads side by side 10 m north of a camera looking north at them
HEADS = """
[[world.signals]]
name = "nb"
x = -1.0
y = 10.0
yaw = 270.0
signal_group = 2
[[world.signals]]
name = "eb"
x = 1.0
y = 10.0
yaw = 270.0
signal_group = 4
instance = "tlc"
[[world.cameras]]
name = "cam"
x = 0.0
y = 1.0
z = 4.5
yaw = 90.0
pitch = 0.0
width = 160
height = 120
fov_deg = 40.0
rate_hz = 1.0
"""


@pytest.fixture
def write(write_scenario, fmu_dir):
    def w(text: str):
        return write_scenario(text.replace("{tlc}", str(fmu_dir / "TrafficLightController.fmu")))
    return w


def test_lamps_for_movement_phase_states():
    assert signals.lit_lamps(3) == ("red",)
    assert signals.lit_lamps(6) == signals.lit_lamps(5) == ("green",)
    assert signals.lit_lamps(7) == ("yellow",) and signals.lit_lamps(8) == ("yellow",)
    assert signals.lit_lamps(1) == () and signals.lit_lamps(42) == ()
    colours = signals.lamp_colours(1)
    assert all(colours[k] == signals.DIM_RGB[k] for k in signals.LAMPS)
    assert signals.lamp_colours(6)["green"] == signals.LIT_RGB["green"] and signals.state_name(4) == "red+yellow"


def lamp_rgba(world: World, head: str) -> dict[str, tuple]:
    """The lamps' colours as pybullet records them: the record TinyRenderer draws from. pybullet's EGL
    renderer keeps its own copy and draws the colour set (the pixels show it), but its getVisualShapeData
    still reports the colour a shape was built with, so under EGL only the pixels can say."""
    data = pb.getVisualShapeData(world.scene.signal_ids[head], physicsClientId=world.scene.client)
    by_link = {d[1]: tuple(round(c, 4) for c in d[7][:3]) for d in data}
    return {lamp: by_link[1 + i] for i, lamp in enumerate(signals.LAMPS)}


def expected_rgba(state: int) -> dict[str, tuple]:
    return {k: tuple(round(c, 4) for c in v) for k, v in signals.lamp_colours(state).items()}


def lit_in_frame(world: World, camera, frame, head: str) -> tuple[str, ...]:
    """The lamps that look lit in the frame: brightest pixel of each lamp at its projected centre
    (3x3 window), lit when at least twice as bright as the darkest lamp."""
    bright = {lamp: int(_lamp_pixels(world, camera, frame, head, lamp).max()) for lamp in signals.LAMPS}
    floor = min(bright.values())
    return tuple(k for k in signals.LAMPS if bright[k] >= 2 * floor and bright[k] > 80)


def _lamp_pixels(world: World, camera, frame, head: str, lamp: str) -> np.ndarray:
    """The 3x3 window of RGB pixels (9, 3) around where the lamp's centre projects."""
    (uv,), depth = camera.project(np.array([world.scene.lamp_centre(head, lamp)]))
    assert depth[0] > 0
    u, v = int(uv[0]), int(uv[1])
    return frame.rgb[v - 1:v + 2, u - 1:u + 2].reshape(-1, 3)


def lamp_hue(frame, camera, world: World, head: str, lamp: str) -> str:
    """The colour a lamp's brightest pixel reads as: red (red well above green), yellow (red and green
    both well above blue) or green (green above red)."""
    window = _lamp_pixels(world, camera, frame, head, lamp).astype(int)
    r, g, b = window[window.sum(axis=1).argmax()]
    if g > r:
        return "green"
    return "yellow" if g > 0.5 * r and min(r, g) > 2 * b else "red"


def test_set_signal_recolours_only_on_change():
    layout = WorldLayout(cameras=[CameraSpec("cam", 0.0, 1.0, 4.5, yaw=90.0, pitch=0.0, width=160, height=120,
                                             fov_deg=40.0)],
                         signals=[SignalSpec("nb", 0.0, 10.0, 270.0, 2, "tlc")])
    with World(layout) as w:
        cam = w.cameras["cam"]
        assert lamp_rgba(w, "nb") == expected_rgba(1)  # built dark
        assert lit_in_frame(w, cam, cam.render(), "nb") == ()
        for state, lit in ((3, ("red",)), (6, ("green",)), (8, ("yellow",)), (4, ("red", "yellow")), (1, ())):
            assert w.set_signal("nb", state)
            assert not w.set_signal("nb", state)  # same state: nothing to do
            if w.scene.renderer_name == "tiny":  # the record is what TinyRenderer draws (lamp_rgba)
                assert lamp_rgba(w, "nb") == expected_rgba(state)
            frame = cam.render()
            assert lit_in_frame(w, cam, frame, "nb") == lit, state
            assert [lamp_hue(frame, cam, w, "nb", lamp) for lamp in lit] == list(lit), state
        # the pole and housing are solid: a ray from the camera hits the head
        hit = pb.rayTest((0.0, 1.0, 4.5), (0.0, 20.0, 4.5), physicsClientId=w.scene.client)[0]
        assert w.scene.labels[hit[0]] == ("signal", "nb")


def test_lamps_follow_controller_over_a_cycle(write, tmp_path):
    from master.run.cosim import CoSimulation

    sc = load_scenario(write(PLAN + HEADS))
    assert [(s.name, s.instance, s.signal_group) for s in sc.world.signals] == [("nb", "tlc", 2), ("eb", "tlc", 4)]
    cosim = CoSimulation(sc, run_dir=tmp_path / "run", quiet=True)
    part = cosim.world
    seen: dict[float, dict] = {}
    lit_seen: dict[float, dict] = {}
    original = part.after_step

    def after_step(k, t_next):
        original(k, t_next)
        w = part.world
        key = round(t_next, 6)
        seen[key] = {h: lamp_rgba(w, h) for h in ("nb", "eb")}
        if key in (2.0, 8.0, 12.0, 18.0):  # green/yellow of group 2, then of group 4
            cam = w.cameras["cam"]
            frame = cam.render(t_next)
            lit_seen[key] = {h: lit_in_frame(w, cam, frame, h) for h in ("nb", "eb")}

    part.after_step = after_step
    result = cosim.run()
    assert result.status == "completed", result.error
    with open(result.run_dir / "timeseries.csv") as f:
        rows = [(round(float(r["time"]), 6), int(float(r["tlc.state_2"])), int(float(r["tlc.state_4"])))
                for r in csv.DictReader(f)]
    assert len(rows) == 201
    states_2 = {s for _, s, _ in rows}
    assert {3, 6, 8} <= states_2  # the plan runs through red, green and yellow
    for t, s2, s4 in rows:
        assert seen[t]["nb"] == expected_rgba(s2), (t, s2)
        assert seen[t]["eb"] == expected_rgba(s4), (t, s4)
    by_t = {t: (s2, s4) for t, s2, s4 in rows}
    for t, lit in lit_seen.items():
        s2, s4 = by_t[t]
        assert lit == {"nb": signals.lit_lamps(s2), "eb": signals.lit_lamps(s4)}, t
    assert lit_seen[2.0]["nb"] == ("green",) and lit_seen[12.0]["eb"] == ("green",)
    # metadata: one change per state transition (plus the first state shown at the start)
    changes_2 = 1 + sum(1 for a, b in zip(rows, rows[1:]) if a[1] != b[1])
    meta = result.metadata["world"]["signals"]
    assert meta["nb"]["changes"] == changes_2 and meta["nb"]["state"] == rows[-1][1]
    assert meta["eb"]["instance"] == "tlc" and meta["eb"]["signal_group"] == 4


BAD = [
    ('[[world.signals]]\nname = "s"\nx = 5.0\ny = 5.0\nsignal_group = 9\n', "world.signals[0].signal_group"),
    ('[[world.signals]]\nname = "s"\nx = 5.0\ny = 5.0\n', "world.signals[0].signal_group: required"),
    ('[[world.signals]]\nname = "s"\nx = 5.0\ny = 5.0\nsignal_group = 2\ninstance = "nope"\n',
     "world.signals[0].instance: no FMU instance 'nope'"),
    ('[[world.signals]]\nname = "s"\nx = 5.0\ny = 5.0\nsignal_group = 2\ninstance = "car"\n',
     "world.signals[0].instance: instance 'car' is not a TrafficLightController"),
    ('[[world.signals]]\nname = "s"\nx = 80.0\ny = 5.0\nsignal_group = 2\n', "world.signals[0]: outside the map"),
    ('[[world.signals]]\nname = "s"\nx = -20.0\ny = -20.0\nsignal_group = 2\n[[world.buildings]]\nname = "b"\n'
     'x = -20.0\ny = -20.0\nsize_x = 10.0\nsize_y = 10.0\nheight = 5.0\n', "world.signals[0]: inside building"),
    ('[[world.signals]]\nname = "s"\nx = 5.0\ny = 5.0\nsignal_group = 2\ncolour = "red"\n',
     "world.signals[0].colour: unknown key"),
]


@pytest.mark.parametrize("extra,expected", BAD, ids=[e for _, e in BAD])
def test_bad_signal_rejected_with_key(write, extra, expected):
    text = PLAN + '[fmus.car]\nfmu = "{vehicle}"\n' + extra
    with pytest.raises(ScenarioError) as err:
        load_scenario(write(text))
    assert any(p.startswith(expected) for p in err.value.problems), err.value.problems


def test_instance_required_without_a_single_controller(write_scenario):
    text = '[time]\nstop = 1.0\nstep = 0.1\n[fmus.car]\nfmu = "{vehicle}"\n' \
           '[[world.signals]]\nname = "s"\nx = 5.0\ny = 5.0\nsignal_group = 2\n'
    with pytest.raises(ScenarioError) as err:
        load_scenario(write_scenario(text))
    assert any(p.startswith("world.signals[0].instance: required when [fmus] has 0 TrafficLightController")
               for p in err.value.problems), err.value.problems
