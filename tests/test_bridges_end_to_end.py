"""Through `v2i run`: the world's camera reaches an RSU app, its frames go over the V2X air to the cav.

Lockstep on the in-process bus: an RSU participant takes each camera frame
(with its simulation time and camera model) and transmits one message per
frame on `v2x/tx/rsu`; a cav participant receives what the air delivers on
`v2x/rx/cav`. The master logs every frame as sent and delivered or dropped.
"""
from __future__ import annotations

import json
import threading
import time
import uuid
from pathlib import Path

import numpy as np

from bridges.camera_stream import CameraSubscriber
from bridges.sensor_stream import decode_fix
from bridges.timesync.participant import Participant
from bridges.transport.memory import MemoryBus
from bridges.v2x import AIR_ARRIVAL, stamp_ns
from master.run.cosim import CoSimulation
from master.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent
CASE = (ROOT / "scenarios" / "ima_world.toml").read_text()


def _scenario(tmp_path, prefix: str) -> Path:
    text = CASE.replace("stop = 8.0", "stop = 1.0")
    text += f"""
[world.vehicles.cav.gnss]
rate_hz = 5.0
sigma_h = 0.5
seed = 3

[bridge]
transport = "memory"
prefix = "{prefix}"
join_timeout_s = 5.0
heartbeat_s = 0.1
heartbeat_timeout_s = 2.0

[participants.rsu]
role = "rsu_app"
latencies = {{ detect = 0.03 }}

[participants.cav]
role = "av_app"

[v2x]
max_range_m = 500.0
[v2x.stations.rsu]
position = [6.5, 6.5, 6.0]
[v2x.stations.cav]
vehicle = "cav"
"""
    text = text.replace("[fmus.cav]\nfmu = \"VehicleDynamics\"", f"[fmus.cav]\nfmu = \"{ROOT}/build/fmus/VehicleDynamics.fmu\"")
    text = text.replace("[fmus.ev]\nfmu = \"VehicleDynamics\"", f"[fmus.ev]\nfmu = \"{ROOT}/build/fmus/VehicleDynamics.fmu\"")
    path = tmp_path / "e2e.toml"
    path.write_text(text)
    return path


def _rsu(prefix, out):
    bus = MemoryBus(prefix=prefix, sender="rsu")
    cam = CameraSubscriber(bus, "rsu_cam")
    p = Participant(bus, "rsu", "rsu_app")

    def run():
        try:
            p.join(5)
            for tick in p.ticks():
                frame = cam.get(timeout=0.0)
                if frame is not None:
                    assert frame.t <= tick.t + 1e-9
                    out["frames"].append((tick.t, frame.t, frame.frame_id, frame.rgb.shape,
                                          float(np.abs(frame.P).sum())))
                    payload = f"frame {frame.frame_id}".encode().ljust(120, b".")
                    bus.publish("v2x/tx/rsu", payload, p.output_time("detect", tick=tick))
                p.ack(tick)
        finally:
            p.close()
            cam.close()
            bus.close()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def _cav(prefix, out):
    bus = MemoryBus(prefix=prefix, sender="cav")
    rx = bus.subscribe("v2x/rx/cav")
    fixes = bus.subscribe("gnss/cav")
    p = Participant(bus, "cav", "av_app")

    def run():
        try:
            p.join(5)
            out["world"] = p.world
            for tick in p.ticks():
                while (msg := rx.recv(timeout=0.0)) is not None:
                    out["rx"].append((tick.t, msg.t_sim, msg.sender, msg.payload[:9], dict(msg.stamps)))
                while (msg := fixes.recv(timeout=0.0)) is not None:
                    out["fixes"].append(decode_fix(msg.payload))
                p.ack(tick)
        finally:
            p.close()
            bus.close()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def test_camera_to_rsu_app_and_v2x_through_the_air_to_the_cav(tmp_path, fmu_dir):
    prefix = f"test/e2e-{uuid.uuid4().hex[:8]}"
    out = {"frames": [], "rx": [], "fixes": []}
    opened = time.time()
    apps = [_rsu(prefix, out), _cav(prefix, out)]
    result = CoSimulation(load_scenario(_scenario(tmp_path, prefix)), tmp_path / "run", quiet=True).run()
    for th in apps:
        th.join(5)
    assert result.status == "completed", result.error
    # the join reply: the scenario's geodetic origin and the Unix time of simulation time 0
    assert out["world"]["origin"] == {"lat": 42.2808, "lon": -83.743, "alt": 260.0}  # bridges.geo default
    assert opened - 1 < out["world"]["epoch_unix_s"] < time.time()
    assert out["world"]["intersection"]["road_width"] == 7.0
    # camera: 10 Hz frames of 640x480 with their camera model, seen at the tick of their own time
    frames = out["frames"]
    assert [f[2] for f in frames] == list(range(len(frames))) and 9 <= len(frames) <= 11
    assert all(abs(tick_t - frame_t) < 1e-9 for tick_t, frame_t, *_ in frames)
    assert all(shape == (480, 640, 3) and psum > 0 for *_, shape, psum in frames)
    # V2X: each frame transmitted 30 ms after its tick, received through the channel after that
    assert len(out["rx"]) >= len(frames) - 1
    for tick_t, arrival, sender, head, stamps in out["rx"]:
        assert sender == "master" and head.startswith(b"frame ")
        assert stamps[AIR_ARRIVAL] == stamp_ns(arrival)  # the air stamps the arrival for the latency chain
        fid = int(head.split()[1].rstrip(b"."))
        t_tx = frames[fid][1] + 0.03
        assert t_tx < arrival < t_tx + 0.01 and arrival <= tick_t + 1e-9
    # GNSS at 5 Hz near the true lane centre x = 1.75
    assert 4 <= len(out["fixes"]) <= 6 and all(abs(f.x - 1.75) < 3 for f in out["fixes"])
    # the master's record: counts and the event log, line by line
    meta = json.loads((tmp_path / "run" / "metadata.json").read_text())
    v2x = meta["v2x"]
    assert v2x["sent"] == len(frames) and v2x["delivered"] == len(out["rx"]) + v2x["in_flight_at_end"]
    events = [json.loads(line) for line in (tmp_path / "run" / "events.jsonl").read_text().splitlines()]
    sent = [e for e in events if e["event"] == "v2x_sent"]
    assert len(sent) == len(frames) and all(e["from"] == "rsu" and e["bytes"] == 120 for e in sent)
    delivered = [e for e in events if e["event"] == "v2x_delivered"]
    assert all(e["to"] == "cav" and e["latency_s"] > 0 for e in delivered)
    # the frame of t = stop (1.0 s) is published after the last step; no tick follows to see it
    assert meta["streams"]["published"]["camera"] == len(frames) + 1


def test_v2x_without_a_bridge_is_refused_naming_both_tables(tmp_path, fmu_dir):
    import pytest

    from master.errors import ScenarioError

    text = CASE + '\n[v2x]\n[v2x.stations.rsu]\nposition = [6.5, 6.5, 6.0]\n'
    path = tmp_path / "nobridge.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=r"v2x: needs a \[bridge\] table"):
        load_scenario(path)
