"""master.report.page: the HTML page and the clip from a run folder (a synthetic one here; the case-study
tests check a real run's report)."""
from __future__ import annotations

import csv
import json
import math
import re

import cv2
import numpy as np
import pytest
import tomli_w

from bridges import v2x
from master.run.collision import Body, CollisionCheck
from master.run.metrics import TRACE
from master.report.page import ReportError, load_run, verdict_lines, write_report

CAR, VAN = Body("cav", 4.5, 1.8, 1.0), Body("ev", 6.5, 2.3, 1.42)


def make_run(root, name="run", brake=False, frames=12):
    run = root / name
    run.mkdir()
    dt, n = 0.05, 120
    rows, check = [], CollisionCheck({"cav": CAR, "ev": VAN})
    for k in range(n + 1):
        t = k * dt
        v_cav = 8.0 if not brake else max(0.0, 8.0 - 4.0 * t)
        y = -30 + (8.0 * t if not brake else 8.0 * min(t, 2.0) - 2.0 * min(t, 2.0) ** 2)
        cav, ev = (1.75, y, math.pi / 2, v_cav), (-60 + 16 * t, -1.75, 0.0, 16.0)
        rows.append([t, *cav, *ev])
        check.update(t, {"cav": cav, "ev": ev})
    with open(run / "timeseries.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "cav.x", "cav.y", "cav.yaw", "cav.v", "ev.x", "ev.y", "ev.yaw", "ev.v"])
        w.writerows(rows)
    metrics = {**check.metrics(), "time_mode": "lockstep", "latency_policy": "fixed"}
    (run / "metrics.json").write_text(json.dumps(metrics))
    (run / "metadata.json").write_text(json.dumps({"scenario": name, "status": "completed"}))
    world = {"intersection": {"road_width": 7.0, "arm_length": 60.0},
             "buildings": [{"name": "sw", "x": -30.0, "y": -30.0, "size_x": 48.0, "size_y": 48.0, "height": 15.0}],
             "cameras": [{"name": "rsu_cam", "x": 6.5, "y": 6.5}],
             "vehicles": {"cav": {"length": 4.5, "width": 1.8, "rear_overhang": 1.0},
                          "ev": {"length": 6.5, "width": 2.3, "rear_overhang": 1.42}}}
    (run / "scenario.resolved.toml").write_text(tomli_w.dumps({"world": world}))
    cam = run / "camera" / "rsu_cam"
    cam.mkdir(parents=True)
    with open(cam / "frames.csv", "w") as f:
        f.write("frame_id,t,file\n")
        for i in range(frames):
            img = np.full((480, 640, 3), 40 + 10 * i, np.uint8)
            cv2.imwrite(str(cam / f"{i:06d}.jpg"), img)
            f.write(f"{i},{i * 0.1},{i:06d}.jpg\n")
    ns = v2x.stamp_ns
    with open(run / TRACE, "w") as f:
        for i in range(frames):
            f.write(json.dumps({"kind": "detections", "camera": "rsu_cam", "frame_id": i, "t": i * 0.1,
                                "objects": [{"box": [100, 100, 200, 160], "label": "emergency", "score": 0.9,
                                             "track": 3, "bsm_id": "a1b2c3d4"}]}) + "\n")
            f.write(json.dumps({"stamps": {v2x.FRAME: ns(i * 0.1), v2x.DETECT_END: ns(i * 0.1 + 0.03),
                                           v2x.SEND: ns(i * 0.1 + 0.031), v2x.AIR_ARRIVAL: ns(i * 0.1 + 0.032)},
                                "can_counter": None}) + "\n")
    return run


def test_report_of_one_run_has_every_plot_and_a_playable_clip(tmp_path):
    import av

    run = make_run(tmp_path)
    page, clips = write_report([run])
    text = page.read_text()
    assert page == run / "report.html"
    assert "collision: true" in text and "cav and ev touch" in text
    assert len(re.findall(r"<img alt='([^']+)' src='data:image/png;base64,", text)) == 4  # top-down, latency, 2 shared
    assert "data:video/mp4;base64," in text and clips[0]["frames"] == 12
    with av.open(str(run / "camera.mp4")) as container:
        codec = container.streams.video[0].codec_context.name
        decoded = [f for f in container.decode(video=0)]
    assert len(decoded) == 12 and (decoded[0].width, decoded[0].height) == (640, 480) and codec == "h264"


def test_two_runs_side_by_side(tmp_path):
    a, b = make_run(tmp_path, "with_cps", brake=True), make_run(tmp_path, "no_cps")
    page, _ = write_report([a, b])
    text = page.read_text()
    assert page.name == "report-vs-no_cps.html" and "with_cps vs no_cps" in text
    assert "collision: false" in text and "collision: true" in text


def test_verdict_lines():
    assert verdict_lines({}) == []
    lines = verdict_lines({"collision": False, "min_gap_m": 3.2, "min_ttc_s": None, "pet_s": 1.5,
                           "latency_ms": {"e2e": {"p50": 120.0, "p99": 180.0, "n": 40}},
                           "time_mode": "lockstep", "latency_policy": "measured"})
    assert lines == ["collision: false", "min gap 3.20 m, min TTC n/a, PET 1.50 s",
                     "E2E latency p50 120.0 ms, p99 180.0 ms (n = 40; lockstep, measured latency policy)"]


def test_verdict_lines_of_a_realtime_run_give_the_apps_clock_bounds():
    metrics = {"latency_ms": {"e2e": {"p50": 60.0, "p99": 90.0, "n": 12}}, "time_mode": "realtime", "rtf": 0.5,
               "latency_policy": "measured", "clock_bound_ms": {"cav": 0.0881, "rsu": 0.1123}}
    lines = verdict_lines(metrics)
    assert lines[1] == "  wall clock at RTF 0.5: p50 120.0 ms, p99 180.0 ms"
    assert lines[2] == ("  stages stamped by an app and the master are good to the app's clock-offset bound: "
                        "cav ±0.09 ms, rsu ±0.11 ms (E2E is on the master's clock alone)")
    assert len(verdict_lines({**metrics, "clock_bound_ms": None})) == 2


def test_not_a_run_folder(tmp_path):
    with pytest.raises(ReportError, match="no timeseries.csv"):
        load_run(tmp_path)
