"""Camera frames on the bus: raw and JPEG round trips with the camera model, and bad payloads."""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from bridges.camera_stream import CameraStreamError, decode_frame, encode_frame
from master.scenario.loader import load_scenario
from master.world.world import World

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def frame():
    layout = load_scenario(ROOT / "scenarios" / "ima_world.toml").world
    with World(layout) as w:
        w.pose_vehicle("cav", 1.75, -20.0, np.pi / 2)
        w.pose_vehicle("ev", -25.0, -1.75, 0.0)
        return w.cameras["rsu_cam"].render(1.5)


def test_raw_round_trip_is_exact(frame):
    got = decode_frame(encode_frame(frame, "raw"))
    assert got.camera == "rsu_cam" and got.frame_id == frame.frame_id and got.t == 1.5
    assert np.array_equal(got.rgb, frame.rgb)
    for name in ("P", "K", "R_wc", "position"):
        assert np.allclose(getattr(got, name), getattr(frame, name))


def test_jpeg_is_smaller_and_close(frame):
    raw, jpeg = encode_frame(frame, "raw"), encode_frame(frame, "jpeg", quality=90)
    assert len(jpeg) < len(raw) / 5
    got = decode_frame(jpeg)
    assert got.rgb.shape == frame.rgb.shape
    assert np.mean(np.abs(got.rgb.astype(int) - frame.rgb.astype(int))) < 3.0


def _with_header(frame, **changes):
    payload = encode_frame(frame, "raw")
    (n,) = struct.unpack_from(">I", payload)
    header = json.loads(payload[4:4 + n])
    header.update(changes)
    for k, v in list(header.items()):
        if v is None:
            del header[k]
    head = json.dumps(header).encode()
    return struct.pack(">I", len(head)) + head + payload[4 + n:]


@pytest.mark.parametrize("payload_of, reason", [
    (lambda f: b"", "truncated"),
    (lambda f: struct.pack(">I", 999) + b"{}", "truncated: header says 999"),
    (lambda f: struct.pack(">I", 3) + b"{x}", "header: not JSON"),
    (lambda f: _with_header(f, P=None), "header: missing P"),
    (lambda f: _with_header(f, P=[[float("nan")] * 4] * 3), "header.P: contains NaN"),
    (lambda f: _with_header(f, K=[[1, 2], [3, 4]]), "header.K: expected shape"),
    (lambda f: _with_header(f, width=641), "raw image: expected"),
    (lambda f: _with_header(f, width=-1), "header.width/height"),
    (lambda f: _with_header(f, encoding="png"), "header.encoding"),
    (lambda f: _with_header(f, encoding="jpeg"), "jpeg: OpenCV could not decode"),
    (lambda f: encode_frame(f, "raw")[:-10], "raw image: expected"),
])
def test_bad_payloads_say_why(frame, payload_of, reason):
    with pytest.raises(CameraStreamError, match=reason.replace("(", r"\(").replace("[", r"\[")):
        decode_frame(payload_of(frame))


def test_encode_refuses_bad_images(frame):
    from dataclasses import replace

    with pytest.raises(CameraStreamError, match="uint8"):
        encode_frame(replace(frame, rgb=frame.rgb.astype(np.float32)))
    with pytest.raises(CameraStreamError, match="encoding"):
        encode_frame(frame, "webp")
