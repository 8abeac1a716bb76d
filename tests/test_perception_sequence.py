"""Render -> detect -> project -> track on a stretch of the IMA case-study sequence, scored on truth.

Every sequence test scores the chain the RSU app runs (`chain="app"`: its
PerceptionStage at the default Settings, the tracks it would broadcast). Detectors
over the same frames: an oracle reading the renderer's segmentation with the
vehicles' true kinds (isolates projection and tracking: their own error), the same
oracle with every box pushed 12 px down (the score must see a broken projection),
the oracle with the labels swapped (the score must see a wrong class), and the
shipped torch weights (the whole chain). The evaluation lives in evaluation/ (it
needs the simulator's world, which the RSU app never imports).
"""
from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("pybullet")
torch = pytest.importorskip("torch")

from master.world.ground_truth import mask_box  # noqa: E402
from rsu_app.config import Settings  # noqa: E402
from rsu_app.perception import make_detector  # noqa: E402
from rsu_app.perception.detector import Detection  # noqa: E402
from evaluation.tracker_sequence import evaluate_sequence  # noqa: E402

SCENARIO = Path(__file__).resolve().parent.parent / "scenarios" / "ima_world.toml"
# The app runs from t = 0 and starts tracks out to perception.track_range_m (90 m): the ev is within 90 m of
# the camera from t = 1.0 s and within the 60 m scored (and broadcast) from t = 2.8 s, so the stretch starts
# where its track would.
STRETCH = dict(start=1.0, stop=5.5, min_age=1.0)
KINDS = {"cav": "car", "ev": "emergency"}  # scenarios/ima_world.toml [world.vehicles.*] kind
SWAPPED = {"car": "emergency", "emergency": "car"}
torch.set_num_threads(1)


class Oracle:
    """The true visible box of every vehicle with >= 40 visible pixels, shifted by `dv` pixels, labelled
    with the vehicle's kind (or the other kind with `swap`)."""
    name = "oracle"

    def __init__(self, dv: float = 0.0, swap: bool = False):
        self.dv, self.swap = dv, swap

    def detect(self, rgb):
        raise AssertionError("the oracle needs the whole frame")

    def detect_frame(self, frame, world):
        out = []
        for name, body in world.scene.vehicle_ids.items():
            m = frame.seg == body
            if m.sum() >= 40:
                u0, v0, u1, v1 = mask_box(m)
                kind = world.layout.vehicles[name].kind
                out.append(Detection((u0, v0 + self.dv, u1, v1 + self.dv), SWAPPED[kind] if self.swap else kind, 1.0))
        return out


@pytest.fixture(scope="module")
def oracle_report(fmu_dir):
    return evaluate_sequence(SCENARIO, Oracle(), **STRETCH)


def test_projection_and_tracking_alone_are_accurate(oracle_report):
    rep = oracle_report
    assert rep.chain == "app" and rep.operating_point["score_threshold"] == Settings().detector.score_threshold
    assert rep.operating_point["track_range_m"] == Settings().perception.track_range_m, rep.table()
    assert rep.frames == 46 and rep.samples >= 48, rep.table()  # measured 52
    # measured: position median 0.112 p90 0.172 m, speed median 0.054 m/s, heading median 0.18 deg, coverage
    # cav 0.957 (its first second has no track old enough) ev 1.0
    assert rep.position_error["median"] <= 0.2 and rep.position_error["p90"] <= 0.3, rep.table()
    assert rep.speed_error["median"] <= 0.1 and rep.heading_error["median"] <= 0.5, rep.table()
    assert rep.coverage["cav"] >= 0.9 and rep.coverage["ev"] >= 0.95, rep.table()
    assert rep.false_tracks == 0 and rep.false_rows == [] and rep.false_per_10s == 0.0, rep.table()
    assert rep.id_switches == 0 and rep.class_errors == 0, rep.table()
    assert rep.duration_s == pytest.approx(4.6), rep.table()
    vehicles = {r["vehicle"] for r in rep.rows}
    assert vehicles == {"cav", "ev"}, vehicles


def test_tracks_carry_the_vehicles_class(oracle_report, fmu_dir):
    """The RSU must flag the emergency vehicle: its track says "emergency", the car's "car"; a detector that
    swaps the classes shows as class errors on every scored track-frame."""
    labels = {n: {r["label"] for r in oracle_report.rows if r["vehicle"] == n} for n in KINDS}
    assert labels == {n: {k} for n, k in KINDS.items()}, labels
    assert oracle_report.class_accuracy == {"cav": 1.0, "ev": 1.0}, oracle_report.table()

    rep = evaluate_sequence(SCENARIO, Oracle(swap=True), start=3.0, stop=4.5, min_age=0.5)
    assert rep.samples >= 10 and rep.class_errors == rep.samples, rep.table()
    assert rep.class_accuracy == {"cav": 0.0, "ev": 0.0}, rep.table()
    labels = {n: {r["label"] for r in rep.rows if r["vehicle"] == n} for n in KINDS}
    assert labels == {n: {SWAPPED[k]} for n, k in KINDS.items()}, labels


def test_a_biased_box_shows_in_the_position_error(fmu_dir):
    rep = evaluate_sequence(SCENARIO, Oracle(dv=12.0), start=3.0, stop=4.5, min_age=0.5)
    # tracks land metres off (some beyond the match radius: false tracks, lost coverage)
    assert rep.samples >= 5 and rep.position_error["median"] > 1.0, rep.table()
    assert rep.false_tracks > 0 or min(rep.coverage.values()) < 0.8, rep.table()
    assert len(rep.false_rows) == rep.false_tracks


def test_shipped_detector_tracks_both_vehicles_through_the_case_study(fmu_dir):
    """The shipped weights through the app's chain at its defaults over the whole case-study sequence (0-8 s),
    held to what RECIPE.md and the README claim. Measured: 85 track-frames scored, position 0.198 m, speed
    0.153 m/s, heading 0.33 deg (medians), coverage cav 0.971 (68/70) ev 0.974 (37/38), no false track-frame,
    id switch or class error. Margins: about 15 % on the medians, one frame on coverage. The issue's goal of
    <= 1 false track-frame per 10 s is held exactly (in 8.1 s: none)."""
    rep = evaluate_sequence(SCENARIO, make_detector("torch", threads=1))
    print(rep.table())
    assert rep.chain == "app" and rep.frames == 81 and rep.samples >= 80, rep.table()
    assert rep.position_error["median"] <= 0.23 and rep.speed_error["median"] <= 0.18, rep.table()
    assert rep.heading_error["median"] <= 0.4, rep.table()
    assert rep.coverage["cav"] >= 0.95 and rep.coverage["ev"] >= 0.947, rep.table()
    assert rep.false_per_10s <= 1.0 and rep.false_tracks == 0 and rep.id_switches == 0, rep.table()
    assert rep.class_errors == 0 and rep.class_accuracy == {"cav": 1.0, "ev": 1.0}, rep.table()


def test_cli_eval_tracker(fmu_dir, capsys, tmp_path):
    import json

    from master.cli import main

    short = ["--scenario", str(SCENARIO), "--start", "4.0", "--stop", "4.6", "--min-age", "0.2", "--json"]
    reports = {}
    for chain in ("app", "tracker"):
        assert main(["eval-tracker", *short, "--chain", chain]) == 0
        reports[chain] = rep = json.loads(capsys.readouterr().out)
        assert rep["chain"] == chain and rep["frames"] == 7 and rep["detector"] == "torch", rep
        assert set(rep["coverage"]) == {"cav", "ev"} and "rows" not in rep and "false_rows" not in rep, rep
        assert rep["position_error"]["median"] is not None and rep["position_error"]["median"] < 1.0, rep
        assert rep["duration_s"] == pytest.approx(0.7) and rep["class_errors"] == 0, rep
    assert reports["app"]["operating_point"]["score_threshold"] == Settings().detector.score_threshold
    assert reports["tracker"]["operating_point"]["score_threshold"] is None
    assert main(["eval-tracker", *short, "--confirm-hits", "2", "--gate", "9.21"]) == 0
    op = json.loads(capsys.readouterr().out)["operating_point"]
    assert op["confirm_hits"] == 2 and op["gate"] == 9.21, op
    # bad overrides: exit 2 before anything loads, each named by its flag
    assert main(["eval-tracker", *short, "--score-threshold", "1.5"]) == 2
    err = capsys.readouterr().err
    assert "--score-threshold" in err and "<= 1" in err, err
    assert main(["eval-tracker", *short, "--confirm-hits", "6", "--meas-std", "zero"]) == 2
    err = capsys.readouterr().err
    assert "--confirm-hits" in err and "--meas-std" in err, err
    assert main(["eval-tracker", *short, "--chain", "tracker", "--score-threshold", "0.5"]) == 2
    assert "--score-threshold" in capsys.readouterr().err
    assert main(["eval-tracker", "--scenario", str(tmp_path / "none.toml")]) == 2
    assert "error" in capsys.readouterr().err
    assert main(["eval-tracker", "--scenario", str(SCENARIO), "--start", "5", "--stop", "4"]) == 2
