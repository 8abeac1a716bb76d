"""The [world] table: a good layout loads; every bad layout is rejected naming its key."""
from __future__ import annotations

import pytest

from master.errors import ScenarioError
from master.scenario.loader import load_scenario

BASE = """
[time]
stop = 1.0
step = 0.1
[fmus.car]
fmu = "{vehicle}"
[fmus.car.parameters]
x0 = 1.75
y0 = -40.0
yaw0 = 1.5707963267948966
[world.intersection]
arm_length = 60.0
"""
BUILDING_A = """
[[world.buildings]]
name = "a"
x = -20.0
y = -20.0
size_x = 20.0
size_y = 20.0
height = 10.0
"""


def test_good_world_loads(write_scenario):
    sc = load_scenario(write_scenario(BASE + BUILDING_A + """
[[world.cameras]]
name = "cam"
x = 8.0
y = 8.0
z = 6.0
[world.vehicles.car]
length = 4.0
[world.vehicles.car.lidar]
channels = 8
"""))
    w = sc.world
    assert [b.name for b in w.buildings] == ["a"] and w.buildings[0].bounds == ((-30, -30, 0), (-10, -10, 10))
    assert w.cameras[0].rate_hz == 10.0  # default rate
    car = w.vehicles["car"]
    assert car.lidar.channels == 8
    # default rear overhang: (length - default wheelbase 2.3927) / 2
    assert car.rear_overhang == pytest.approx((4.0 - 2.3927) / 2)
    assert sc.resolved()["world"]["buildings"][0]["name"] == "a"


BAD = [
    (BUILDING_A + BUILDING_A.replace('"a"', '"b"').replace("-20.0", "-15.0"),
     "world.buildings[1]: overlaps world.buildings[0]"),
    (BUILDING_A + '[[world.cameras]]\nname = "c"\nx = -20.0\ny = -20.0\nz = 5.0\n',
     "world.cameras[0]: inside building world.buildings[0]"),
    (BUILDING_A.replace("size_x = 20.0", "size_x = 0.0"), "world.buildings[0].size_x: must be > 0"),
    (BUILDING_A.replace("height = 10.0", "height = -1.0"), "world.buildings[0].height: must be > 0"),
    (BUILDING_A.replace("x = -20.0", "x = 0.0"), "world.buildings[0]: stands on the carriageway"),
    (BUILDING_A.replace("x = -20.0", "x = -80.0"), "world.buildings[0]: outside the map"),
    ("[world.vehicles.bus]\nlength = 10.0\n", "world.vehicles.bus: no FMU instance 'bus'"),
    ("[world.vehicles.car]\nlength = 0.0\n", "world.vehicles.car.length: must be > 0"),
    ("[world.vehicles.car]\nwidth = -2.0\n", "world.vehicles.car.width: must be > 0"),
    ("[world.vehicles.car]\nkind = \"tank\"\n", "world.vehicles.car.kind: expected one of car, emergency"),
    ("[world.vehicles.car]\ncolor = [1.0, 2.0, 0.0]\n", "world.vehicles.car.color: expected [r, g, b]"),
    ("[world.vehicles.car.lidar]\nchannels = 0\n", "world.vehicles.car.lidar.channels: must be > 0"),
    ("[world.vehicles.car]\nrear_overhang = 9.0\n", "world.vehicles.car.rear_overhang: must be shorter"),
    ('[[world.cameras]]\nname = "c"\nx = 0.0\ny = 0.0\nz = 5.0\nwidth = 0\n', "world.cameras[0].width: must be > 0"),
    ('[[world.cameras]]\nname = "c"\nx = 0.0\ny = 0.0\nz = 5.0\nfov_deg = 180.0\n', "world.cameras[0].fov_deg"),
    ("[world.foo]\nx = 1\n", "world: unknown key 'foo'"),
]


@pytest.mark.parametrize("extra,expected", BAD, ids=[e for _, e in BAD])
def test_bad_world_rejected_with_key(write_scenario, extra, expected):
    with pytest.raises(ScenarioError) as err:
        load_scenario(write_scenario(BASE + extra))
    assert any(p.startswith(expected) for p in err.value.problems), err.value.problems


def test_vehicle_starting_outside_the_map(write_scenario):
    text = BASE.replace("y0 = -40.0", "y0 = -100.0") + "[world.vehicles.car]\n"
    with pytest.raises(ScenarioError) as err:
        load_scenario(write_scenario(text))
    assert any(p.startswith("world.vehicles.car: starts outside the map") for p in err.value.problems)


def test_validate_cli_reports_world_key(write_scenario, capsys):
    from master.cli import main

    path = write_scenario(BASE + BUILDING_A.replace("size_x = 20.0", "size_x = 0.0"))
    assert main(["validate", str(path)]) == 2
    out = capsys.readouterr()
    assert "world.buildings[0].size_x: must be > 0" in out.out + out.err


def test_resolved_world_loads_again(write_scenario, tmp_path):
    """The run folder's scenario.resolved.toml, world included (signals, gnss), is a valid scenario."""
    import tomli_w

    sc = load_scenario(write_scenario(BASE + BUILDING_A + """
[world.vehicles.car]
color = [0.2, 0.4, 0.6]
[world.vehicles.car.gnss]
sigma_h = 1.5
[world.vehicles.car.lidar]
channels = 8
"""))
    from master.run.recorder import _toml_safe

    path = tmp_path / "resolved.toml"
    path.write_text(tomli_w.dumps(_toml_safe(sc.resolved())))
    again = load_scenario(path)
    assert again.world == sc.world
    assert again.world.vehicles["car"].gnss.sigma_h == 1.5
