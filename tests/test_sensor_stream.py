"""Lidar scans and GNSS fixes on the bus: round trips and bad payloads."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from bridges.sensor_stream import GnssFix, SensorStreamError, decode_fix, decode_scan, encode_fix, encode_scan
from master.world.lidar import Scan


def _scan():
    pts = np.array([[1.0, 2.0, 0.5], [10.0, -3.0, 1.0], [4.0, 4.0, 0.0]])
    return Scan(t=1.2, points=pts, body_ids=np.array([7, 3, 7]), n_rays=1024, pose=(1.75, -20.0, 1.57))


def test_scan_round_trip_keeps_points_and_labels():
    got = decode_scan(encode_scan(_scan(), {7: ("vehicle", "ev"), 3: ("building", "sw_corner")}))
    assert got.t == 1.2 and got.n_rays == 1024 and got.pose == (1.75, -20.0, 1.57)
    assert np.allclose(got.points, _scan().points) and got.points.dtype == np.float32
    assert got.labels == ["vehicle:ev", "building:sw_corner", "vehicle:ev"]


def test_fix_round_trip():
    fix = GnssFix(0.5, 1.0, 2.0, 1.5, 0.1, 8.3)
    assert decode_fix(encode_fix(fix)) == fix


@pytest.mark.parametrize("payload, reason", [
    (b"\x00\x00", "lidar: truncated"),
    (struct.pack(">I", 50) + b"{}", "lidar: truncated: header says 50"),
    (struct.pack(">I", 2) + b"[]", "lidar: header: not a JSON object"),
    (struct.pack(">I", 2) + b"{}", "lidar: bad header"),
])
def test_bad_scans_say_why(payload, reason):
    with pytest.raises(SensorStreamError, match=reason):
        decode_scan(payload)


def test_scan_with_a_wrong_body_length_or_label_index_is_refused():
    good = encode_scan(_scan(), {})
    with pytest.raises(SensorStreamError, match="3 points need 42 bytes"):
        decode_scan(good[:-1])
    (n,) = struct.unpack_from(">I", good)
    header = json.loads(good[4:4 + n])
    header["labels"] = header["labels"][:1]
    head = json.dumps(header).encode()
    with pytest.raises(SensorStreamError, match="label index is out of range"):
        decode_scan(struct.pack(">I", len(head)) + head + good[4 + n:])


@pytest.mark.parametrize("payload, reason", [
    (b"nope", "gnss: not JSON"), (b"[1]", "not a JSON object"), (b'{"t": 1}', "gnss: missing x"),
    (b'{"t":1,"x":"a","y":0,"z":0,"heading":0,"speed":0}', "not a number"),
    (b'{"t":1,"x":NaN,"y":0,"z":0,"heading":0,"speed":0}', "NaN"),
])
def test_bad_fixes_say_why(payload, reason):
    with pytest.raises(SensorStreamError, match=reason):
        decode_fix(payload)
