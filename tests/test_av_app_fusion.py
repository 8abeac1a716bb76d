"""AV app fusion: a V2X object and the lidar track of the same vehicle become one object, also where the
lidar sees only part of the vehicle (its box centre then lies up to half the hidden size off)."""
from __future__ import annotations

import pytest

from av_app.config import FusionSection
from av_app.fusion import fuse
from av_app.obu import V2xObject
from av_app.perception import LidarObject


def bsm(x: float, y: float, length: float = 6.5, width: float = 2.3) -> V2xObject:
    return V2xObject("v2x:ev", "rsu", 6.0, x, y, 0.0, 11.2, 0.0, length, width, True, True, 0.5, 1)


def track(x: float, y: float, length: float, width: float) -> LidarObject:
    return LidarObject("lidar:1", 6.0, x, y, -0.3, 11.7, 11.2, -3.4, length, width, False, 5, 0.3)


def test_a_partly_seen_vehicle_fuses_with_its_bsm():
    """Issue 38, 25 mph 2.5 s late: the ev's front coming out past the corner building, a 2.05 x 0.23 m box
    3.1 m ahead of the ev's BSM (6.5 x 2.3 m), was a second object for one plan and the cav braked at
    4.3 m/s^2 for it. Its centre can be (6.5 - 2.05) / 2 m along and (2.3 - 0.23) / 2 m across off: one
    object, the BSM's identity and emergency flag, the partial box counting for little in the position."""
    (obj,) = fuse([bsm(-36.4, -1.6)], [track(-33.4, -2.5, 2.05, 0.23)], 6.0, FusionSection())
    assert obj.source == "both" and obj.id == "v2x:ev" and obj.lidar_id == "lidar:1" and obj.emergency
    assert obj.x == pytest.approx(-36.4, abs=0.3) and obj.length == 6.5


def test_a_whole_box_as_far_from_the_bsm_is_another_vehicle():
    """The gate grows only by what the box misses: a whole vehicle-sized box 3.1 m away stays its own object
    (the gate is 3.0 m), and so does a partial box beyond the grown gate."""
    objs = fuse([bsm(-36.4, -1.6)], [track(-33.4, -2.5, 6.5, 2.3)], 6.0, FusionSection())
    assert sorted(o.source for o in objs) == ["lidar", "v2x"]
    objs = fuse([bsm(-36.4, -1.6)], [track(-30.4, -1.6, 2.05, 0.23)], 6.0, FusionSection())  # 6 m > 3 + 2.4
    assert sorted(o.source for o in objs) == ["lidar", "v2x"]
