"""AP, ignore handling and recall bins of the detector evaluation, against hand-computed values."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rsu_app.perception.dataset import Dataset, Sample, Truth
from rsu_app.perception.detector import Detection
from rsu_app.perception.evaluate import average_precision, evaluate_detections, iou_matrix


def _ds(truths_per_image: list[list[Truth]]) -> Dataset:
    samples = [Sample(i, None, 640, 480, t) for i, t in enumerate(truths_per_image)]
    return Dataset(None, samples, {1: "car", 2: "emergency"}, {})


def _t(box, label="car", **kw) -> Truth:
    return Truth(tuple(float(b) for b in box), label, **kw)


def _d(box, score, label="car") -> Detection:
    return Detection(tuple(float(b) for b in box), label, score)


def test_iou():
    m = iou_matrix([[0, 0, 10, 10], [5, 5, 15, 15]], [[0, 0, 10, 10], [10, 10, 20, 20], [0, 0, 0, 0]])
    assert m[0, 0] == 1.0 and m[0, 1] == 0.0 and m[1, 0] == pytest.approx(25 / 175) and m[1, 1] == pytest.approx(25 / 175)
    assert m[0, 2] == 0.0  # empty box: no NaN


def test_perfect_and_empty():
    ds = _ds([[_t((10, 10, 50, 40)), _t((100, 100, 180, 150), "emergency")], []])
    perfect = [[_d((10, 10, 50, 40), 0.9), _d((100, 100, 180, 150), 0.8, "emergency")], []]
    r = evaluate_detections(ds, perfect)
    assert r.ap50 == {"car": 1.0, "emergency": 1.0, "overall": 1.0} and r.ap["overall"] == 1.0
    r = evaluate_detections(ds, [[], []])
    assert r.ap50["overall"] == 0.0
    assert r.recall_by_distance[-1]["bin"] == "unknown" and r.recall_by_distance[-1]["recall"] == 0.0
    assert r.renderer is None and " drawn by " not in r.table()
    ds.renderer = "egl"  # a set's render.json: the report says which renderer's pictures it scored
    r = evaluate_detections(ds, perfect)
    assert r.renderer == "egl" and r.to_dict()["renderer"] == "egl" and "2 images drawn by egl" in r.table()


def test_false_positive_ranked_first_hand_computed():
    """Two truths; detections by score: FP, TP, TP. Precision at recall 0.5 and 1.0 is 2/3
    after making it monotone (1/2 at the first TP, raised to 2/3 by the later point): AP = 2/3."""
    ds = _ds([[_t((0, 0, 10, 10)), _t((20, 20, 30, 30))]])
    dets = [[_d((50, 50, 60, 60), 0.9), _d((0, 0, 10, 10), 0.8), _d((20, 20, 30, 30), 0.7)]]
    r = evaluate_detections(ds, dets)
    # recall points 0..0.5 (51 of them) and 0.51..1.0 (50) all have interpolated precision 2/3
    assert r.ap50["car"] == pytest.approx(2 / 3)
    assert math.isnan(r.ap50["emergency"]) and r.ap50["overall"] == pytest.approx(2 / 3)
    assert average_precision(np.array([1, 0]), np.array([0.9, 0.8]), 2) == pytest.approx(51 / 101)


def test_localisation_error_hurts_strict_thresholds_only():
    ds = _ds([[_t((0, 0, 100, 100))]])
    r = evaluate_detections(ds, [[_d((10, 0, 110, 100), 0.9)]])  # IoU 90/110 = 0.818
    assert r.ap50["car"] == 1.0
    assert r.ap["car"] == pytest.approx(7 / 10)  # thresholds 0.5 .. 0.80 pass, 0.85 .. 0.95 fail


def test_ignored_truths_neither_miss_nor_false_positive():
    ds = _ds([[_t((0, 0, 10, 10)), _t((200, 200, 204, 203), ignore=True)]])
    # a detection on the ignored truth, scored above the real one: dropped, AP stays 1
    r = evaluate_detections(ds, [[_d((200, 200, 204, 203), 0.95), _d((0, 0, 10, 10), 0.5)]])
    assert r.ap50["car"] == 1.0 and r.truths["car"] == 1
    # the ignored one not found: not a miss
    assert evaluate_detections(ds, [[_d((0, 0, 10, 10), 0.5)]]).ap50["car"] == 1.0
    # the same detection on a truth that is not ignored would be a real truth: recall 1/2 at most
    ds2 = _ds([[_t((0, 0, 10, 10)), _t((200, 200, 204, 203))]])
    assert evaluate_detections(ds2, [[_d((0, 0, 10, 10), 0.5)]]).ap50["car"] == pytest.approx(51 / 101)


def test_wrong_class_is_false_positive_and_miss():
    ds = _ds([[_t((0, 0, 10, 10), "emergency")]])
    r = evaluate_detections(ds, [[_d((0, 0, 10, 10), 0.9, "car")]])
    assert r.ap50["emergency"] == 0.0 and math.isnan(r.ap50["car"])


def test_recall_by_distance_and_occlusion():
    truths = [[_t((0, 0, 10, 10), distance=5.0, occlusion=0.0), _t((20, 0, 30, 10), distance=25.0, occlusion=0.3),
               _t((40, 0, 50, 10), distance=45.0, occlusion=0.6), _t((60, 0, 70, 10), distance=80.0, occlusion=0.8),
               _t((80, 0, 90, 10), distance=85.0, occlusion=0.1)]]
    dets = [[_d((0, 0, 10, 10), 0.9), _d((40, 0, 50, 10), 0.9), _d((80, 0, 90, 10), 0.2)]]
    r = evaluate_detections(_ds(truths), dets, operating_threshold=0.3)
    by_d = {row["bin"]: (row["found"], row["truths"]) for row in r.recall_by_distance}
    assert by_d == {"0-20": (1, 1), "20-40": (0, 1), "40-60": (1, 1), "60+": (0, 2)}  # 0.2 < threshold
    by_o = {row["bin"]: (row["found"], row["truths"]) for row in r.recall_by_occlusion}
    assert by_o == {"0-0.25": (1, 2), "0.25-0.5": (0, 1), "0.5-0.75": (1, 1), "0.75-1": (0, 1)}
    json.dumps(r.to_dict())  # NaN-free, serialisable
    assert "recall by distance" in r.table()


def test_recall_by_distance_per_class():
    truths = [[_t((0, 0, 10, 10), "emergency", distance=5.0), _t((20, 0, 30, 10), "emergency", distance=45.0),
               _t((40, 0, 50, 10), distance=5.0), _t((60, 0, 70, 10), distance=45.0)]]
    # the far emergency vehicle is boxed as a car: found for neither class
    dets = [[_d((0, 0, 10, 10), 0.9, "emergency"), _d((20, 0, 30, 10), 0.9), _d((40, 0, 50, 10), 0.9),
             _d((60, 0, 70, 10), 0.9)]]
    r = evaluate_detections(_ds(truths), dets)
    rows = {c: {row["bin"]: (row["found"], row["truths"]) for row in bins if row["truths"]}
            for c, bins in r.recall_by_class_distance.items()}
    assert rows == {"car": {"0-20": (1, 1), "40-60": (1, 1)}, "emergency": {"0-20": (1, 1), "40-60": (0, 1)}}
    assert "distance (m), emergency" in r.table()


def test_mismatched_lengths():
    with pytest.raises(ValueError, match="1 detection lists for 2 images"):
        evaluate_detections(_ds([[], []]), [[]])



def test_ap50_interval_resamples_images_and_narrows_with_more_of_them():
    """`bootstrap`: a 95 % interval of AP50 from image resamples. Each image holds one car; the detector finds
    it in every other image (AP50 51/101, recall 1/2). Resampling images, recall is a binomial share, so the
    interval's width is about 4 standard errors, 4 sqrt(0.25 / N): 0.41 for 24 images, 0.1 for 400. Perfect
    boxes give [1, 1]; the same seed the same interval; emergency vehicles absent: no interval for them."""
    from rsu_app.perception.evaluate import bootstrap_ap50

    def case(n):
        ds = _ds([[_t((10, 10, 50, 40))] for _ in range(n)])
        return ds, [[_d((10, 10, 50, 40), 0.5 + i / (4 * n))] if i % 2 == 0 else [] for i in range(n)]

    widths = {}
    for n in (24, 400):
        ds, dets = case(n)
        r = evaluate_detections(ds, dets, bootstrap=1000, seed=1)
        lo, hi = r.ap50_interval["car"]
        assert r.ap50["car"] == pytest.approx(51 / 101) and lo < r.ap50["car"] < hi
        assert r.ap50_interval["overall"] == r.ap50_interval["car"] and "emergency" not in r.ap50_interval
        assert r.bootstrap == 1000 and "AP50 95 % interval (1000 image resamples)" in r.table()
        widths[n] = hi - lo
        assert evaluate_detections(ds, dets, bootstrap=1000, seed=1).ap50_interval == r.ap50_interval
    assert widths[24] == pytest.approx(4 * math.sqrt(0.25 / 24), rel=0.25)
    assert widths[400] == pytest.approx(4 * math.sqrt(0.25 / 400), rel=0.25)
    ds = _ds([[_t((10, 10, 50, 40)), _t((100, 100, 180, 150), "emergency")], [_t((0, 0, 20, 20))]])
    perfect = [[_d((10, 10, 50, 40), 0.9), _d((100, 100, 180, 150), 0.8, "emergency")], [_d((0, 0, 20, 20), 0.7)]]
    assert evaluate_detections(ds, perfect, bootstrap=50).ap50_interval == {
        "car": [1.0, 1.0], "emergency": [1.0, 1.0], "overall": [1.0, 1.0]}
    assert evaluate_detections(ds, perfect).ap50_interval == {}  # off unless asked
    with pytest.raises(ValueError, match="bootstrap: the number of resamples must be >= 0, got -1"):
        evaluate_detections(ds, perfect, bootstrap=-1)
    with pytest.raises(ValueError, match="must be >= 1, got 0"):
        bootstrap_ap50({}, 0)

# -- ground error of the boxes ----------------------------------------------------------------------------------
def _ground_case():
    """The case study's RSU camera and three vehicles on the south road (west of the pole): their exact boxes
    (the projected 3D box the fit models), a dataset holding them and the camera."""
    from master.world.layout import CameraSpec, WorldLayout
    from master.world.world import World
    from rsu_app.perception.geo import VEHICLE_SIZE, CameraModel, _box_corners

    spec = CameraSpec(name="c", width=640, height=480, x=6.5, y=6.5, z=6.0, yaw=225.0, pitch=-14.0, roll=0.0,
                      fov_deg=100.0)
    with World(WorldLayout(cameras=[spec])) as w:
        c = w.cameras["c"]
        cam = CameraModel(c.K, c.R_wc, c.position)
    truths = []
    for x, label in ((-10.0, "car"), (-30.0, "emergency"), (-50.0, "car")):
        uv, _ = cam.project(_box_corners(x, -1.75, 0.0, *VEHICLE_SIZE[label]))
        box = (*uv.min(axis=0), *uv.max(axis=0))
        dist = float(np.hypot(x - cam.position[0], -1.75 - cam.position[1]))
        truths.append(_t(box, label, position=(x, -1.75), heading=0.0, distance=dist, occlusion=0.0))
    camera = {"K": np.asarray(cam.K).tolist(), "R_wc": np.asarray(cam.R_wc).tolist(),
              "position": np.asarray(cam.position).tolist()}
    ds = Dataset(None, [Sample(0, None, 640, 480, truths, camera=camera)], {1: "car", 2: "emergency"}, {})
    return ds, truths


def test_ground_error_of_boxes_per_class_and_distance():
    """Exact boxes land on the true centres (the detector's and the true ones alike); a box whose bottom edge
    is 6 px low puts the vehicle metres nearer along the ray; a box below the score threshold, or of the wrong
    class, finds nothing; the rows are per class and distance band and the JSON holds no NaN."""
    from rsu_app.perception.evaluate import evaluate_ground

    ds, (near, ev, far) = _ground_case()
    low = np.array(far.box) + [0, 0, 0, 6.0]
    dets = [[_d(near.box, 0.9), _d(ev.box, 0.9, "emergency"), _d(low, 0.9), _d(near.box, 0.5, "emergency")]]
    rep = evaluate_ground(ds, dets, "toy")
    rows = {(r["class"], r["boxes"], r["heading"], r["bin"]): r for r in rep.rows}
    for label, b in (("car", "0-20"), ("emergency", "20-40"), ("car", "40-60")):
        r = rows[(label, "true", "known", b)]
        assert r["n"] == 1 and r["median_m"] < 0.05, r
    assert rows[("car", "detector", "known", "0-20")]["median_m"] < 0.05
    assert rows[("emergency", "detector", "known", "20-40")]["median_m"] < 0.05
    assert rows[("car", "detector", "known", "40-60")]["median_m"] > 1.0  # the low bottom edge
    assert rows[("car", "detector", "known", "all")]["n"] == 2
    far_sample = [s for s in rep.samples if s["boxes"] == "detector" and s["distance"] > 40 and s["heading"] == "known"]
    assert far_sample[0]["along_m"] < -1.0 and abs(far_sample[0]["across_m"]) < 0.5 * abs(far_sample[0]["along_m"])
    # the emergency vehicle's 0.5-score box on the near car neither finds it nor counts at threshold 0.6
    assert rows[("emergency", "detector", "known", "all")]["n"] == 1
    high = evaluate_ground(ds, dets, "toy", score_threshold=0.95)
    assert not [r for r in high.rows if r["boxes"] == "detector"]
    d = rep.to_dict()
    assert d["rows"][0]["nees"] is not None
    json.dumps(d, allow_nan=False)  # an empty band is null, not NaN
    assert "median" in rep.table() and "emergency" in rep.table()
