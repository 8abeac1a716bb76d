"""Detector evaluation on a dataset folder: COCO-style AP, recall by distance and occlusion, FPS.

AP follows the COCO recipe: per class, detections of all images sorted by
score, greedy matching to the best-IoU unmatched truth at each IoU
threshold (truths not flagged "ignore" first), precision made monotone and
sampled at 101 recall points. A detection matched to an ignored truth is
dropped (neither true nor false positive); ignored truths are never misses.
"Overall" is the mean over classes that have truths (COCO's mAP).
With `bootstrap`, AP50 also gets a 95 % interval from resampling the images
(`bootstrap_ap50`): a 400-frame set holds about 300 emergency vehicles, so one
vehicle moves its AP50 by about 0.003, and whether 0.947 misses a 0.95 target
is a question of that spread.
Recall by distance/occlusion counts non-ignored truths found at IoU 0.5
(class-aware) among the detector's outputs at its own score threshold; by
distance also per class, since the emergency vehicle is the object the case
study exists for and an overall figure can hide it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from rsu_app.perception.dataset import Dataset, Truth
from rsu_app.perception.detector import Detection, Detector

IOU_THRESHOLDS = np.round(np.arange(0.5, 0.96, 0.05), 2)
RECALL_POINTS = np.linspace(0, 1, 101)
DISTANCE_BINS = (0.0, 20.0, 40.0, 60.0, math.inf)
OCCLUSION_BINS = (0.0, 0.25, 0.5, 0.75, 1.0 + 1e-9)


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box in a (N, 4) with every box in b (M, 4), boxes as u0, v0, u1, v1."""
    a, b = np.asarray(a, float).reshape(-1, 4), np.asarray(b, float).reshape(-1, 4)
    iw = np.clip(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0, None)
    ih = np.clip(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0, None)
    inter = iw * ih
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def match(dets: list[Detection], truths: list[Truth], thr: float) -> tuple[np.ndarray, np.ndarray]:
    """Greedy COCO matching in one image, one class. Returns per detection 1 (TP), 0 (FP), -1 (dropped:
    matched an ignored truth), and per truth the index of its detection or -1."""
    order = np.argsort([-d.score for d in dets], kind="stable")
    ign = np.array([t.ignore for t in truths], bool)
    # truths not ignored first, so a detection prefers them (COCO sorts gt by ignore flag)
    gt_order = np.argsort(ign, kind="stable")
    ious = iou_matrix([dets[i].box for i in order], [truths[j].box for j in gt_order]) if truths else None
    det_state = np.zeros(len(dets), int)
    gt_match = -np.ones(len(truths), int)
    for r, di in enumerate(order):
        best, best_iou = -1, min(thr, 1 - 1e-10)
        for c, gj in enumerate(gt_order):
            if gt_match[gj] >= 0 and not ign[gj]:
                continue
            if best >= 0 and not ign[gt_order[best]] and ign[gj]:
                break  # already matched a real truth; ignored ones come last
            if ious[r, c] < best_iou:
                continue
            best, best_iou = c, ious[r, c]
        if best < 0:
            continue
        gj = gt_order[best]
        gt_match[gj] = di
        det_state[di] = -1 if ign[gj] else 1
    return det_state, gt_match


def average_precision(tp: np.ndarray, scores: np.ndarray, n_truth: int) -> float:
    """101-point interpolated AP from per-detection TP flags (FP = 0) and scores; NaN without truths."""
    if n_truth == 0:
        return float("nan")
    if len(tp) == 0:
        return 0.0
    order = np.argsort(-scores, kind="mergesort")
    tp = tp[order].astype(float)
    ctp, cfp = np.cumsum(tp), np.cumsum(1 - tp)
    recall = ctp / n_truth
    precision = ctp / np.maximum(ctp + cfp, np.finfo(float).eps)
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    idx = np.searchsorted(recall, RECALL_POINTS, side="left")
    return float(np.mean([precision[i] if i < len(precision) else 0.0 for i in idx]))


@dataclass
class Report:
    detector: str
    images: int
    truths: dict[str, int]
    ap50: dict[str, float]
    ap: dict[str, float]  # AP@0.5:0.95
    recall_by_distance: list[dict] = field(default_factory=list)
    recall_by_occlusion: list[dict] = field(default_factory=list)
    recall_by_class_distance: dict[str, list[dict]] = field(default_factory=dict)
    fps: float = float("nan")
    ms_per_frame: dict[str, float] = field(default_factory=dict)
    ap50_interval: dict[str, list[float]] = field(default_factory=dict)  # 95 % bootstrap interval; {} when off
    bootstrap: int = 0  # image resamples behind ap50_interval
    renderer: str | None = None  # what drew the set's images (its render.json), None where not recorded

    def to_dict(self) -> dict:
        from dataclasses import asdict

        return finite_or_none(asdict(self))

    def table(self) -> str:
        f = lambda x: "  n/a" if not math.isfinite(x) else f"{x:5.3f}"  # noqa: E731
        drawn = f" drawn by {self.renderer}" if self.renderer else ""
        lines = [f"detector {self.detector}: {self.images} images{drawn}, {self.fps:.1f} FPS "
                 f"(p50 {self.ms_per_frame.get('p50', float('nan')):.1f} ms)",
                 f"{'class':<10} {'truths':>6} {'AP50':>6} {'AP':>6}"
                 + (f"  AP50 95 % interval ({self.bootstrap} image resamples)" if self.ap50_interval else "")]
        for c in [*self.truths, "overall"]:
            n = self.truths.get(c, sum(self.truths.values()))
            ci = self.ap50_interval.get(c)
            lines.append(f"{c:<10} {n:>6} {f(self.ap50[c]):>6} {f(self.ap[c]):>6}"
                         + (f"  {f(ci[0])} - {f(ci[1])}" if ci else ""))
        for title, rows in (("distance (m)", self.recall_by_distance),
                            *((f"distance (m), {c}", r) for c, r in self.recall_by_class_distance.items()),
                            ("occlusion", self.recall_by_occlusion)):
            lines.append(f"recall by {title}:")
            for r in rows:
                lines.append(f"  {r['bin']:<12} {r['found']:>5}/{r['truths']:<5} {f(r['recall'])}")
        return "\n".join(lines)


def _bin_label(lo: float, hi: float) -> str:
    return f"{lo:g}+" if math.isinf(hi) else f"{lo:g}-{round(hi, 6):g}"


def _recall_bins(found: list[tuple[float | None, bool]], edges) -> list[dict]:
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = [ok for v, ok in found if v is not None and lo <= v < hi]
        rows.append({"bin": _bin_label(lo, hi), "truths": len(sel), "found": int(sum(sel)),
                     "recall": sum(sel) / len(sel) if sel else float("nan")})
    unknown = [ok for v, ok in found if v is None]
    if unknown:
        rows.append({"bin": "unknown", "truths": len(unknown), "found": int(sum(unknown)),
                     "recall": sum(unknown) / len(unknown)})
    return rows


def bootstrap_ap50(per_class: dict[str, tuple[list[np.ndarray], list[np.ndarray], np.ndarray]], n_boot: int,
                   seed: int = 0, level: float = 0.95) -> dict[str, list[float]]:
    """Percentile interval of AP50 per class and overall (the mean over classes) from `n_boot` resamples of the
    images with replacement. `per_class[c]`: per image, the TP flags (1/0) and scores of the class's detections
    matched at IoU 0.5, and its count of truths not ignored. Images, not detections, are resampled: the
    vehicles of one frame share its camera and light, so they are not independent draws."""
    if n_boot < 1:
        raise ValueError(f"bootstrap: the number of resamples must be >= 1, got {n_boot}")
    rng = np.random.default_rng(seed)
    flat = {}
    for c, (tps, scores, n) in per_class.items():
        img = np.repeat(np.arange(len(tps)), [len(t) for t in tps])
        flat[c] = (np.concatenate(tps) if tps else np.zeros(0), np.concatenate(scores) if scores else np.zeros(0),
                   img, np.asarray(n))
    n_img = len(next(iter(per_class.values()))[2]) if per_class else 0
    have = [c for c in per_class if flat[c][3].sum() > 0]
    draws: dict[str, list[float]] = {c: [] for c in [*per_class, "overall"]}
    for _ in range(n_boot):
        counts = np.bincount(rng.integers(0, n_img, n_img), minlength=n_img)
        for c, (tp, sc, img, n) in flat.items():
            w = counts[img]
            draws[c].append(average_precision(np.repeat(tp, w), np.repeat(sc, w), int(counts @ n)))
        vals = [draws[c][-1] for c in have if math.isfinite(draws[c][-1])]
        draws["overall"].append(float(np.mean(vals)) if vals else float("nan"))
    q = [100 * (1 - level) / 2, 100 * (1 + level) / 2]
    return {c: [float(x) for x in np.nanpercentile(v, q)] for c, v in draws.items()
            if np.isfinite(v).any()}


def evaluate_detections(ds: Dataset, detections: list[list[Detection]], detector: str = "?",
                        classes=("car", "emergency"), operating_threshold: float = 0.0, bootstrap: int = 0,
                        seed: int = 0) -> Report:
    """Score per-image detections (in dataset order) against the dataset's truths; `bootstrap` > 0: also a
    95 % interval of AP50 from that many image resamples (`bootstrap_ap50`, seeded by `seed`)."""
    if bootstrap < 0:
        raise ValueError(f"bootstrap: the number of resamples must be >= 0, got {bootstrap}")
    if not ds.samples:
        raise ValueError(f"{ds.root}: the dataset has no images")
    if len(detections) != len(ds.samples):
        raise ValueError(f"{len(detections)} detection lists for {len(ds.samples)} images")
    ap50, ap = {}, {}
    n_truth = {}
    found_dist: list[tuple[float | None, bool]] = []
    found_occ: list[tuple[float | None, bool]] = []
    by_class: dict[str, list[dict]] = {}
    per_image: dict[str, tuple[list[np.ndarray], list[np.ndarray], np.ndarray]] = {}
    for c in classes:
        found_c: list[tuple[float | None, bool]] = []
        tps: dict[float, list[np.ndarray]] = {float(t): [] for t in IOU_THRESHOLDS}
        scs: dict[float, list[np.ndarray]] = {float(t): [] for t in IOU_THRESHOLDS}
        n_img = []
        for s, dets in zip(ds.samples, detections):
            d = [x for x in dets if x.label == c]
            g = [t for t in s.truths if t.label == c]
            n_img.append(sum(not t.ignore for t in g))
            sc = np.array([x.score for x in d], float)
            for thr in map(float, IOU_THRESHOLDS):
                state, gt_match = match(d, g, thr)
                keep = state >= 0
                tps[thr].append(state[keep])
                scs[thr].append(sc[keep])
                if thr == float(IOU_THRESHOLDS[0]):
                    for t, m in zip(g, gt_match):
                        if not t.ignore:
                            ok = bool(m >= 0 and d[m].score >= operating_threshold)
                            found_dist.append((t.distance, ok))
                            found_c.append((t.distance, ok))
                            found_occ.append((t.occlusion, ok))
        n = n_truth[c] = sum(n_img)
        per_image[c] = (tps[float(IOU_THRESHOLDS[0])], scs[float(IOU_THRESHOLDS[0])], np.array(n_img))
        by_class[c] = _recall_bins(found_c, DISTANCE_BINS)
        aps = [average_precision(np.concatenate(tps[thr]), np.concatenate(scs[thr]), n)
               for thr in map(float, IOU_THRESHOLDS)]
        ap50[c], ap[c] = aps[0], float(np.mean(aps)) if n else float("nan")
    have = [c for c in classes if n_truth[c] > 0]
    ap50["overall"] = float(np.mean([ap50[c] for c in have])) if have else float("nan")
    ap["overall"] = float(np.mean([ap[c] for c in have])) if have else float("nan")
    return Report(detector, len(ds.samples), n_truth, ap50, ap,
                  _recall_bins(found_dist, DISTANCE_BINS), _recall_bins(found_occ, OCCLUSION_BINS), by_class,
                  ap50_interval=bootstrap_ap50(per_image, bootstrap, seed) if bootstrap else {},
                  bootstrap=bootstrap, renderer=ds.renderer)


def detect_all(detector: Detector, ds: Dataset, warmup: int = 2) -> tuple[list[list[Detection]], list[float]]:
    """Run `detector` over every image: its detections and the seconds of each call (image loading excluded).

    A detector with `set_background` (the classical one) gets each image's empty-scene image
    when the dataset has one (image field "background"), since each frame may have its own
    camera pose and light."""
    if not ds.samples:
        raise ValueError(f"{ds.root}: the dataset has no images")
    dets, times = [], []
    for i, s in enumerate(ds.samples):
        rgb = s.load()
        bg = s.background()
        if bg is not None and hasattr(detector, "set_background"):
            detector.set_background(bg)
        if i == 0:
            for _ in range(warmup):
                detector.detect(rgb)
        t0 = time.perf_counter()
        dets.append(detector.detect(rgb))
        times.append(time.perf_counter() - t0)
    return dets, times


def evaluate(detector: Detector, ds: Dataset, warmup: int = 2, detections: list | None = None,
             bootstrap: int = 0) -> Report:
    """Run `detector` over every image (`detect_all`) and score it; `detections`, when given a list, receives
    the per-image detections (for `evaluate_ground` on the same boxes); `bootstrap`: AP50's interval from
    that many image resamples (`bootstrap_ap50`)."""
    dets, times = detect_all(detector, ds, warmup)
    if detections is not None:
        detections[:] = dets
    rep = evaluate_detections(ds, dets, detector.name, operating_threshold=0.0, bootstrap=bootstrap)
    if times:
        t = np.array(times) * 1000
        rep.fps = float(1000 / t.mean())
        rep.ms_per_frame = {"mean": float(t.mean()), "p50": float(np.percentile(t, 50)),
                            "p95": float(np.percentile(t, 95))}
    return rep


# -- where the boxes put the vehicles on the ground ------------------------------------------------------------
GROUND_DISTANCE_BINS = (0.0, 20.0, 40.0, 60.0, 80.0, math.inf)
GROUND_SCORE = 0.6  # the RSU app's default score threshold: the boxes that reach its tracker


@dataclass
class GroundReport:
    """How far from the true vehicle centre `geo.box_to_ground` puts each found vehicle, per class and
    distance band, for the detector's boxes beside the true visible boxes (what any box-based method gets
    with a perfect detector), with the heading known (a track's: the app's steady state) and searched (a
    new track's). `nees`: the mean normalised error e^T C^-1 e under `geo.ground_fix`'s covariance C, which
    is 2 when C is right (chi-square, 2 dof); `within_2sigma`: the share of errors inside the 2-sigma
    ellipse (0.865 when right)."""
    detector: str
    score_threshold: float
    noise: dict
    rows: list[dict] = field(default_factory=list)  # per class, box source, heading and distance band
    samples: list[dict] = field(default_factory=list, repr=False)  # per found vehicle

    def to_dict(self, samples: bool = False) -> dict:
        d = {"detector": self.detector, "score_threshold": self.score_threshold, "noise": self.noise,
             "rows": self.rows}
        if samples:
            d["samples"] = self.samples
        return finite_or_none(d)

    def table(self) -> str:
        f = lambda x: "  n/a" if x is None or not math.isfinite(x) else f"{x:5.2f}"  # noqa: E731
        lines = [f"ground error of {self.detector}'s boxes (score >= {self.score_threshold:g}, matched at IoU "
                 f"0.5) beside the true boxes; box noise {self.noise}",
                 f"{'class':<10} {'boxes':<9} {'heading':<8} {'range':<7} {'n':>4} {'median':>6} {'p90':>6} "
                 f"{'NEES':>6} {'in 2s':>6}"]
        for r in self.rows:
            lines.append(f"{r['class']:<10} {r['boxes']:<9} {r['heading']:<8} {r['bin']:<7} {r['n']:>4} "
                         f"{f(r['median_m']):>6} {f(r['p90_m']):>6} {f(r['nees']):>6} {f(r['within_2sigma']):>6}")
        return "\n".join(lines)


def finite_or_none(x):
    """x with every non-finite float (in dicts and lists too) as None: JSON has no NaN or inf."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [finite_or_none(v) for v in x]
    return x


def ground_samples(ds: Dataset, detections: list[list[Detection]], score_threshold: float = GROUND_SCORE,
                   noise=None, true_boxes: bool = True, searched: bool = True) -> list[dict]:
    """One record per (found vehicle, box source, heading mode): error (m) from the true centre, and its
    along- and across-ray parts, and the NEES under `geo.ground_fix`'s covariance. A vehicle is found when
    a detection of its class with score >= `score_threshold` matches it at IoU 0.5 (the COCO matching of
    `match`); vehicles flagged ignore, or without position/heading/camera in the dataset, are skipped."""
    from rsu_app.perception.geo import BoxNoise, CameraModel, GeoError, ground_fix

    noise = noise or BoxNoise()
    out = []
    for s, dets in zip(ds.samples, detections):
        if not s.camera:
            continue
        cam = CameraModel.from_dict(s.camera)
        for c in {t.label for t in s.truths}:
            d = [x for x in dets if x.label == c and x.score >= score_threshold]
            g = [t for t in s.truths if t.label == c]
            _, gt_match = match(d, g, 0.5)
            for t, m in zip(g, gt_match):
                if t.ignore or t.position is None or t.heading is None:
                    continue
                sources = [("detector", d[m].box)] if m >= 0 else []
                if true_boxes:
                    sources.append(("true", t.box))
                for src, box in sources:
                    for mode in ("known", "searched") if searched else ("known",):
                        try:
                            p, C = ground_fix(box, cam, c, heading=t.heading if mode == "known" else None,
                                              noise=noise)
                        except (GeoError, ValueError, np.linalg.LinAlgError):
                            continue
                        e = p - np.asarray(t.position, float)
                        ray = np.asarray(t.position, float) - cam.position[:2]
                        ray /= max(np.linalg.norm(ray), 1e-9)
                        out.append({"image": s.image_id, "class": c, "boxes": src, "heading": mode,
                                    "distance": t.distance, "occlusion": t.occlusion,
                                    "error_m": float(np.linalg.norm(e)), "along_m": float(e @ ray),
                                    "across_m": float(e[0] * -ray[1] + e[1] * ray[0]),
                                    "nees": float(e @ np.linalg.solve(C, e)),
                                    "sigma_along_m": float(math.sqrt(ray @ C @ ray))})
    return out


def summarise_ground(samples: list[dict], classes=("car", "emergency")) -> list[dict]:
    """Rows per class, box source, heading mode and distance band (and "all" bands): median and p90 error,
    mean NEES, share within the 2-sigma ellipse (NEES <= 4.0 for 2 dof: chi2.ppf(0.865, 2))."""
    rows = []
    bins = list(zip(GROUND_DISTANCE_BINS[:-1], GROUND_DISTANCE_BINS[1:])) + [(0.0, math.inf)]
    for c in classes:
        for src in ("detector", "true"):
            for mode in ("known", "searched"):
                sel = [x for x in samples if x["class"] == c and x["boxes"] == src and x["heading"] == mode]
                if not sel:
                    continue
                for k, (lo, hi) in enumerate(bins):
                    b = [x for x in sel if x["distance"] is not None and lo <= x["distance"] < hi]
                    e = np.array([x["error_m"] for x in b])
                    n = np.array([x["nees"] for x in b])
                    rows.append({"class": c, "boxes": src, "heading": mode,
                                 "bin": "all" if k == len(bins) - 1 else _bin_label(lo, hi), "n": len(b),
                                 "median_m": float(np.median(e)) if len(b) else float("nan"),
                                 "p90_m": float(np.percentile(e, 90)) if len(b) else float("nan"),
                                 "nees": float(n.mean()) if len(b) else float("nan"),
                                 "within_2sigma": float(np.mean(n <= 4.0)) if len(b) else float("nan")})
    return rows


def evaluate_ground(ds: Dataset, detections: list[list[Detection]], detector: str = "?",
                    score_threshold: float = GROUND_SCORE, noise=None, true_boxes: bool = True) -> GroundReport:
    from dataclasses import asdict

    from rsu_app.perception.geo import BoxNoise

    noise = noise or BoxNoise()
    samples = ground_samples(ds, detections, score_threshold, noise, true_boxes)
    return GroundReport(detector, score_threshold, asdict(noise), summarise_ground(samples), samples)
