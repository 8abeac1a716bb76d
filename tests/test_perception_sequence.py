"""Render -> detect -> project -> track on a stretch of the IMA case-study sequence, scored on truth.

Three detectors over the same frames: an oracle reading the renderer's
segmentation (isolates projection and tracking: their own error), the same
oracle with every box pushed 12 px down (the score must see a broken
projection), and the shipped torch weights (the whole chain; bounds looser
than the full-sequence figures in rsu_app/perception/weights/RECIPE.md). The evaluation lives in
evaluation/ (it needs the simulator's world, which the RSU app never imports).
"""
from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("pybullet")
torch = pytest.importorskip("torch")

from master.world.ground_truth import mask_box  # noqa: E402
from rsu_app.perception import make_detector  # noqa: E402
from rsu_app.perception.detector import Detection  # noqa: E402
from evaluation.tracker_sequence import evaluate_sequence  # noqa: E402

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml"
STRETCH = dict(start=3.0, stop=5.5, min_age=1.0)  # the ev is within 60 m of the camera from t = 2.8 s
torch.set_num_threads(1)


class Oracle:
    """The true visible box of every vehicle with >= 40 visible pixels, shifted by `dv` pixels."""
    name = "oracle"

    def __init__(self, dv: float = 0.0):
        self.dv = dv

    def detect(self, rgb):
        raise AssertionError("the oracle needs the whole frame")

    def detect_frame(self, frame, world):
        out = []
        for name, body in world.scene.vehicle_ids.items():
            m = frame.seg == body
            if m.sum() >= 40:
                u0, v0, u1, v1 = mask_box(m)
                out.append(Detection((u0, v0 + self.dv, u1, v1 + self.dv), world.layout.vehicles[name].kind, 1.0))
        return out


def test_projection_and_tracking_alone_are_accurate(fmu_dir):
    rep = evaluate_sequence(SCENARIO, Oracle(), **STRETCH)
    assert rep.frames == 26 and rep.samples >= 24, rep.table()
    assert rep.position_error["median"] <= 0.3 and rep.position_error["p90"] <= 0.6, rep.table()
    assert rep.speed_error["median"] <= 0.3 and rep.heading_error["median"] <= 2.0, rep.table()
    assert min(rep.coverage.values()) >= 0.8 and rep.false_tracks == 0 and rep.id_switches == 0, rep.table()
    vehicles = {r["vehicle"] for r in rep.rows}
    assert vehicles == {"cav", "ev"}, vehicles


def test_a_biased_box_shows_in_the_position_error(fmu_dir):
    rep = evaluate_sequence(SCENARIO, Oracle(dv=12.0), start=3.0, stop=4.5, min_age=0.5)
    # tracks land metres off (some beyond the match radius: false tracks, lost coverage)
    assert rep.samples >= 5 and rep.position_error["median"] > 1.0, rep.table()
    assert rep.false_tracks > 0 or min(rep.coverage.values()) < 0.8, rep.table()


def test_shipped_detector_tracks_both_vehicles(fmu_dir):
    rep = evaluate_sequence(SCENARIO, make_detector("torch", threads=1), **STRETCH)
    assert rep.samples >= 15, rep.table()
    assert rep.position_error["median"] <= 0.8, rep.table()
    assert rep.speed_error["median"] <= 0.8 and rep.heading_error["median"] <= 8.0, rep.table()
    assert min(rep.coverage.values()) >= 0.7 and rep.id_switches <= 3, rep.table()
    print(rep.table())


def test_cli_eval_tracker(fmu_dir, capsys, tmp_path):
    import json

    from master.cli import main

    assert main(["eval-tracker", "--scenario", str(SCENARIO), "--start", "4.0", "--stop", "4.6", "--min-age", "0.2",
                 "--threads", "1", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["frames"] == 7 and rep["detector"] == "torch" and set(rep["coverage"]) == {"cav", "ev"}
    assert rep["position_error"]["median"] is not None and rep["position_error"]["median"] < 1.0
    assert main(["eval-tracker", "--scenario", str(tmp_path / "none.toml")]) == 2
    assert "error" in capsys.readouterr().err
    assert main(["eval-tracker", "--scenario", str(SCENARIO), "--start", "5", "--stop", "4"]) == 2
