"""A run's verdict through the master: the collision check every step, [time] stop_on, metrics.json, the
console summary, and the records kept for the report (camera frames, trace records).

Two vehicles on crossing lanes (no world renderer needed for the footprints: the world's vehicle table
gives their sizes); the crossing is timed so they touch, or so the second passes behind the first.
"""
from __future__ import annotations

import json

import pytest

from master.run.cosim import CoSimulation
from master.errors import ScenarioError
from master.hooks import Hook
from master.scenario.loader import load_scenario
from master.run.summary import format_summary
from master.run.verdict import realtime_warning

CROSSING = """
[time]
stop = {stop}
step = 0.01
{time_extra}
[fmus.cav]
fmu = "{{vehicle}}"
parameters = {{ x0 = 1.75, y0 = -50.0, yaw0 = 1.5707963267948966, v0 = 8.333, cd_a = 0.0, c_rr = 0.0 }}
[fmus.ev]
fmu = "{{vehicle}}"
parameters = {{ x0 = {ev_x0}, y0 = -1.75, yaw0 = 0.0, v0 = 16.667, cd_a = 0.0, c_rr = 0.0 }}
[record]
variables = ["cav.x", "cav.y", "cav.v", "ev.x", "ev.y", "ev.v"]
{record_extra}
[world.intersection]
road_width = 7.0
[world.vehicles.cav]
length = 4.5
width = 1.8
rear_overhang = 0.95
[world.vehicles.ev]
kind = "emergency"
length = 6.5
width = 2.3
rear_overhang = 1.42
{world_extra}
"""


def crossing(write_scenario, *, stop=8.0, ev_x0=-100.0, time_extra="", record_extra="", world_extra=""):
    return load_scenario(write_scenario(CROSSING.format(stop=stop, ev_x0=ev_x0, time_extra=time_extra,
                                                        record_extra=record_extra, world_extra=world_extra)))


def run(sc, tmp_path, name="run"):
    result = CoSimulation(sc, tmp_path / name, quiet=True).run()
    metrics = json.loads((result.run_dir / "metrics.json").read_text())
    return result, metrics


def rows(result) -> list[list[str]]:
    return [line.split(",") for line in (result.run_dir / "timeseries.csv").read_text().splitlines()[1:]]


def test_the_collision_check_finds_first_contact_and_the_run_goes_on(write_scenario, tmp_path):
    result, m = run(crossing(write_scenario), tmp_path)
    assert result.status == "completed" and len(rows(result)) == 801  # without stop_on the run goes on
    # cav's front bumper reaches the ev's lane edge (y = -3.5 + ... ) while the ev's body spans x = 1.75:
    # footprints first overlap between 5.6 and 5.9 s (constant speeds: see the scenario above)
    assert m["collision"] is True and 5.6 < m["first_collision_s"] < 5.9
    assert m["first_collision"]["pair"] == ["cav", "ev"]
    assert m["first_collision"]["relative_speed_mps"] == pytest.approx((8.333 ** 2 + 16.667 ** 2) ** 0.5, rel=0.01)
    assert m["min_gap_m"] == 0.0 and m["pet_s"] < 0  # both in the conflict zone at once
    events = [json.loads(x) for x in (result.run_dir / "events.jsonl").read_text().splitlines()]
    assert [e["event"] for e in events] == ["collision"] and events[0]["t"] == m["first_collision_s"]
    assert "collision: true — cav and ev touch" in format_summary(result)


def test_a_vehicle_that_crosses_first_gives_a_gap_and_a_positive_pet(write_scenario, tmp_path):
    result, m = run(crossing(write_scenario, ev_x0=-60.0), tmp_path)  # the ev crosses ~2.4 s before the cav
    assert m["collision"] is False and m["first_collision_s"] is None
    assert m["min_gap_m"] > 1.0 and m["pet_s"] > 0.5
    assert "collision: false" in format_summary(result)


def test_stop_on_collision_ends_the_run_at_first_contact(write_scenario, tmp_path):
    sc = crossing(write_scenario, time_extra='stop_on = ["collision"]')
    result, m = run(sc, tmp_path)
    assert result.status == "stopped" and result.error is None
    assert result.metadata["stop_reason"].startswith("collision: cav and ev touch at t = ")
    last_t = float(rows(result)[-1][0])
    assert last_t == pytest.approx(m["first_collision_s"])  # the row of the contact is the last one


def test_stop_on_a_condition_over_signals(write_scenario, tmp_path):
    sc = crossing(write_scenario, time_extra='stop_on = ["distance(cav, ev) < 30 and t > 1"]')
    result, _ = run(sc, tmp_path)
    assert result.status == "stopped"
    last = rows(result)[-1]
    t, cx, cy, ex, ey = float(last[0]), float(last[1]), float(last[2]), float(last[4]), float(last[5])
    assert ((cx - ex) ** 2 + (cy - ey) ** 2) ** 0.5 < 30 and t > 1
    before = rows(result)[-2]
    assert ((float(before[1]) - float(before[4])) ** 2 + (float(before[2]) - float(before[5])) ** 2) ** 0.5 >= 30


@pytest.mark.parametrize("stop_on, reason", [
    ('["cav.vv < 1"]', "unknown signal 'cav.vv'; did you mean 'cav.v'"),
    ('["distance(cav, tree) < 3"]', "distance() needs an instance with x and y outputs"),
    ('["cav.v <"]', "is not an expression"),
    ("3", "expected a list"),
])
def test_bad_stop_on_is_refused_naming_the_entry(write_scenario, stop_on, reason):
    with pytest.raises(ScenarioError) as err:
        crossing(write_scenario, time_extra=f"stop_on = {stop_on}")
    assert "time.stop_on" in str(err.value) and reason in str(err.value)


def test_a_run_without_a_world_has_no_metrics(write_scenario, tmp_path):
    sc = load_scenario(write_scenario('[time]\nstop = 0.1\n[fmus.cav]\nfmu = "{vehicle}"\n'))
    result = CoSimulation(sc, tmp_path / "run", quiet=True).run()
    assert result.status == "completed" and not (result.run_dir / "metrics.json").exists()
    assert "metrics" not in result.metadata


def test_camera_frames_are_kept_for_the_report(write_scenario, tmp_path):
    sc = crossing(write_scenario, stop=0.5, record_extra="camera = true", world_extra="""
[[world.cameras]]
name = "cam"
x = 6.5
y = 6.5
z = 6.0
yaw = 225.0
pitch = -14.0
width = 160
height = 120
rate_hz = 10.0
""")
    result, _ = run(sc, tmp_path)
    folder = result.run_dir / "camera" / "cam"
    lines = (folder / "frames.csv").read_text().splitlines()
    assert lines[0] == "frame_id,t,file" and len(lines) == 1 + 6  # t = 0, 0.1, ..., 0.5
    import cv2

    img = cv2.imread(str(folder / lines[-1].split(",")[2]))
    assert img.shape == (120, 160, 3)
    assert json.loads((folder / "camera.json").read_text())["width"] == 160
    assert result.metadata["camera_archive"]["frames"] == 6


def test_record_camera_needs_a_world(write_scenario):
    with pytest.raises(ScenarioError, match="record.camera: needs a \\[world\\]"):
        load_scenario(write_scenario('[time]\nstop = 0.1\n[fmus.cav]\nfmu = "{vehicle}"\n[record]\ncamera = true\n'))


def test_a_hook_may_stop_the_run_and_every_hook_closes_with_the_outcome(write_scenario, tmp_path):
    seen = {}

    class StopAtHalf(Hook):
        name = "probe"

        def open(self, ctx):
            self.ctx = ctx
            return {"opened": True}

        def after_step(self, k, t_next):
            if t_next >= 0.5 - 1e-9:
                self.ctx.request_stop("probe says so")

        def close(self, outcome):
            seen["outcome"] = outcome
            return {"closed_with": outcome.status}

    sc = crossing(write_scenario)
    cosim = CoSimulation(sc, tmp_path / "run", quiet=True)
    cosim.extra_hooks.append(StopAtHalf())
    result = cosim.run()
    assert result.status == "stopped" and seen["outcome"].stop_reason == "probe says so"
    assert seen["outcome"].steps_done == 50 and result.metadata["probe"] == {"closed_with": "stopped"}


def test_realtime_warning_is_loud_only_when_real_time_was_not_kept():
    base = {"mode": "realtime", "steps_done": 800, "step_s": 0.01, "rtf": {"achieved": 0.2},
            "realtime": {"target_rtf": 1.0, "deadline_misses": 791, "lag_s": {"p99": 0.5}}}
    text = realtime_warning(base)
    assert "791 of 800 steps missed their deadline" in text and "lag p99 500.0 ms" in text
    kept = {**base, "realtime": {"target_rtf": 1.0, "deadline_misses": 2, "lag_s": {"p99": 0.001}}}
    assert realtime_warning(kept) is None
    assert realtime_warning({**base, "mode": "lockstep"}) is None
