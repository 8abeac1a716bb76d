"""benchmarks/world.py part 6: a realtime case-study run judged against the issue's floors from what it left
(the runs themselves are the benchmark's; here a run folder is written by hand)."""
from __future__ import annotations

import json

import pytest

from benchmarks.world import REALTIME_FLOORS, realtime_figures


def run_folder(tmp_path, late=3, lag_p99=0.0025, e2e_p99=110.0, collision=False, status="completed"):
    (tmp_path / "metadata.json").write_text(json.dumps({
        "status": status, "steps_done": 1200,
        "realtime": {"deadline_misses": late, "lag_s": {"p99": lag_p99, "max": 0.007}, "loop_nice": {"nice": -10}},
        "world": {"cameras": {"rsu_cam": {"frames": 120, "dropped": 0}}}}))
    (tmp_path / "metrics.json").write_text(json.dumps({
        "collision": collision,
        "latency_ms": {"stage1": {"p50": 54.0}, "stage2": {"p50": 1.4}, "air": {"p50": 8.0}, "stage3": {"p50": 19.0},
                       "e2e": {"p50": 90.0, "p99": e2e_p99, "n": 154}}}))
    return tmp_path


def test_a_run_within_every_floor_meets_them(tmp_path):
    fig = realtime_figures(run_folder(tmp_path), "run ima_case_study: completed\n")
    assert fig["meets_floors"] and fig["late_share"] == pytest.approx(3 / 1200)
    assert fig["lag_p99_ms"] == pytest.approx(2.5) and fig["e2e_p99_ms"] == 110.0 and fig["camera_frames"] == 120
    assert fig["stages_p50_ms"] == {"stage1": 54.0, "stage2": 1.4, "air": 8.0, "stage3": 19.0}


@pytest.mark.parametrize("change, output", [
    ({"late": 13}, ""),                                    # 1.08 % of the steps late
    ({"lag_p99": 0.021}, ""),
    ({"e2e_p99": REALTIME_FLOORS["e2e_p99_ms"] + 0.1}, ""),
    ({"collision": True}, ""),
    ({"status": "failed"}, ""),
    ({}, "WARNING master: a participant fell behind\n"),
])
def test_a_run_over_any_floor_does_not(tmp_path, change, output):
    assert not realtime_figures(run_folder(tmp_path, **change), output)["meets_floors"]


def test_a_run_that_left_no_figures_is_named(tmp_path):
    with pytest.raises(KeyError, match="metadata.json"):
        realtime_figures(tmp_path, "")
    run_folder(tmp_path)
    meta = json.loads((tmp_path / "metadata.json").read_text())
    del meta["realtime"]
    (tmp_path / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(KeyError, match="no 'realtime'"):
        realtime_figures(tmp_path, "")
