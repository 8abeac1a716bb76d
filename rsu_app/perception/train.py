"""Training the CenterNet detector on a `v2i dataset` folder.

Deterministic for a given (dataset, seed, epochs, threads, torch build): a
seeded numpy generator drives sampling and augmentation, torch runs with
deterministic algorithms, batches are built in this process.
Augmentation: scale jitter with random placement (one affine warp),
horizontal flip, brightness/contrast/per-channel gain jitter and, with
`occluders`, painted occluders: half-hidden vehicles are where the detector
misses most, and the renders hold few of them. Annotations
flagged "ignore", and with `max_occlusion` those more hidden than that, are
masked out of the heatmap loss: the network is neither rewarded nor punished
for firing on them (a vehicle 80 % behind a building is neither a clear
example of a vehicle nor background). `init` starts from a checkpoint's
weights (fine-tuning on a wider dataset) instead of random ones.
"""
from __future__ import annotations

import difflib
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import torch

from rsu_app.perception.dataset import Dataset, Truth, join_datasets, load_dataset
from rsu_app.perception.model import FORMAT, CenterNet, ModelConfig, widen


def _geometry(rng: np.random.Generator, img: np.ndarray, cfg: ModelConfig, scale_jitter: float,
              augment: bool) -> tuple[np.ndarray, np.ndarray]:
    """Frame -> network-input image and the 2x3 matrix taking frame pixels to it.

    Resizing is cv2.resize(INTER_AREA) exactly as `model.preprocess` does at inference, so that the
    un-jittered training image is bit-identical to what the detector sees; the jitter then rescales,
    places the result at a random integer offset (cropping or padding with grey) and maybe mirrors it."""
    W, H = cfg.input_size
    h0, w0 = img.shape[:2]
    if not augment:
        x = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA) if (w0, h0) != (W, H) else img
        return x, np.array([[W / w0, 0, 0], [0, H / h0, 0]], np.float64)
    k = math.exp(rng.uniform(-scale_jitter, scale_jitter))
    w, h = max(8, round(W * k)), max(8, round(H * k))
    small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    dx = int(rng.integers(min(0, W - w), max(0, W - w) + 1))
    dy = int(rng.integers(min(0, H - h), max(0, H - h) + 1))
    out = np.full((H, W, 3), 114, np.uint8)
    xs0, ys0 = max(0, -dx), max(0, -dy)  # source window
    xd0, yd0 = max(0, dx), max(0, dy)  # destination window
    cw, ch = min(w - xs0, W - xd0), min(h - ys0, H - yd0)
    out[yd0:yd0 + ch, xd0:xd0 + cw] = small[ys0:ys0 + ch, xs0:xs0 + cw]
    M = np.array([[w / w0, 0, dx], [0, h / h0, dy]], np.float64)
    if rng.random() < 0.5:
        out = np.ascontiguousarray(out[:, ::-1])
        M = np.array([[-1.0, 0, W], [0, 1, 0]]) @ np.vstack([M, [0, 0, 1]])
    return out, M


def _colour(rng: np.random.Generator, img: np.ndarray) -> np.ndarray:
    x = img.astype(np.float32)
    gain = rng.uniform(0.92, 1.08, 3).astype(np.float32) * rng.uniform(0.75, 1.25)
    mean = x.mean()
    x = (x - mean) * rng.uniform(0.8, 1.2) + mean
    x = x * gain + rng.normal(0, 2.0, x.shape).astype(np.float32)
    return np.clip(x, 0, 255)


# an occluder hides this share of a vehicle's width from one side; a vehicle it leaves less than
# MIN_VISIBLE_SHARE of (of what was visible) is masked out of the loss, like a heavily occluded one
OCCLUDER_SHARE = (0.2, 0.6)
MIN_VISIBLE_SHARE = 0.3


def _occlude(rng: np.random.Generator, img: np.ndarray, boxes: list, ignore: list, p: float) -> None:
    """Paint occluders into `img` (network input, in place) and shrink the visible boxes they hide.

    Each vehicle (not ignored, under 40 % of the image wide) gets one with probability p: a block like the
    corner of a building or a nearer vehicle, covering 20-60 % of the vehicle's width from its left or
    right side, from somewhere above the vehicle down to the bottom of the image (what stands in front is
    nearer, so it reaches lower in the picture), flat-coloured with a gradient and noise. Every box it
    covers over its full height loses that side (the truths are visible boxes); one it hides the bottom of
    across the whole width loses its bottom; a box left with less than `MIN_VISIBLE_SHARE` is ignored."""
    H, W = img.shape[:2]
    for i in range(len(boxes)):
        c0, d0, c1, d1 = boxes[i]
        w = c1 - c0
        if ignore[i] or w < 4 or w > 0.4 * W or rng.random() >= p:
            continue
        share = rng.uniform(*OCCLUDER_SHARE)
        if rng.random() < 0.5:
            a, b = c0 - rng.uniform(0.0, 0.5) * w, c0 + share * w
        else:
            a, b = c1 - share * w, c1 + rng.uniform(0.0, 0.5) * w
        a, b = int(max(0, math.floor(a))), int(min(W, math.ceil(b)))
        top = int(max(0, math.floor(d0 - rng.uniform(0.0, 1.0) * (d1 - d0))))
        if b <= a or top >= H:
            continue
        colour = rng.uniform(30, 225) * rng.uniform(0.85, 1.15, 3)
        ramp = np.linspace(0, rng.uniform(-40, 40), H - top)[:, None, None]
        block = colour[None, None, :] + ramp + rng.normal(0, 4.0, (H - top, b - a, 3))
        img[top:, a:b] = np.clip(block, 0, 255).astype(img.dtype)
        for j, (u0, v0, u1, v1) in enumerate(boxes):
            if b <= u0 or a >= u1 or v1 <= top:
                continue
            before = (u1 - u0) * (v1 - v0)
            if top <= v0:  # covers the box's full height
                if a <= u0 and b >= u1:
                    u1 = u0
                elif a <= u0:
                    u0 = b
                elif b >= u1:
                    u1 = a
            elif a <= u0 and b >= u1:  # hides the box's lower part across its width
                v1 = top
            boxes[j] = (u0, v0, u1, v1)
            if (u1 - u0) * (v1 - v0) < MIN_VISIBLE_SHARE * before or u1 - u0 < 1 or v1 - v0 < 1:
                ignore[j] = True


HEAT_SIGMA = 1 / 6  # the heat target's standard deviation as a share of the box's width and height


def _draw_gaussian(heat: np.ndarray, cx: float, cy: float, w: float, h: float, spread: float = HEAT_SIGMA) -> None:
    """Splat an elliptical gaussian (peak 1 at the centre cell, standard deviations `spread` times the
    box's width and height) into heat, keeping the max."""
    Hh, Wh = heat.shape
    sx, sy = max(0.5, w * spread), max(0.5, h * spread)
    ix, iy = int(cx), int(cy)
    rx, ry = int(3 * sx) + 1, int(3 * sy) + 1
    x0, x1, y0, y1 = max(0, ix - rx), min(Wh, ix + rx + 1), max(0, iy - ry), min(Hh, iy + ry + 1)
    if x0 >= x1 or y0 >= y1:
        return
    xs, ys = np.arange(x0, x1) - ix, np.arange(y0, y1) - iy
    g = np.exp(-(xs[None, :] ** 2) / (2 * sx * sx) - (ys[:, None] ** 2) / (2 * sy * sy))
    heat[y0:y1, x0:x1] = np.maximum(heat[y0:y1, x0:x1], g)


def make_targets(boxes: np.ndarray, labels: np.ndarray, ignore: np.ndarray, cfg: ModelConfig, max_objs: int = 64,
                 size: tuple[int, int] | None = None, heat_sigma: float = HEAT_SIGMA):
    """Boxes (N, 4) in network-input pixels -> heat, heat weight, indices, size, offset, object mask.
    `size` (W, H): the training image size when it is a crop smaller than cfg.input_size. `heat_sigma`:
    the heat target's spread as a share of each box's size (`_draw_gaussian`)."""
    W, H = size or cfg.input_size
    s = cfg.stride
    Wh, Hh = W // s, H // s
    C = len(cfg.classes)
    heat = np.zeros((C, Hh, Wh), np.float32)
    weight = np.ones((C, Hh, Wh), np.float32)
    ind = np.zeros(max_objs, np.int64)
    wh = np.zeros((max_objs, 2), np.float32)
    offset = np.zeros((max_objs, 2), np.float32)
    mask = np.zeros(max_objs, np.float32)
    k = 0
    for (u0, v0, u1, v1), c, ig in zip(boxes, labels, ignore):
        u0, v0, u1, v1 = u0 / s, v0 / s, u1 / s, v1 / s
        if ig:
            weight[:, max(0, int(v0)):int(math.ceil(v1)), max(0, int(u0)):int(math.ceil(u1))] = 0.0
            continue
        w, h = u1 - u0, v1 - v0
        cx, cy = (u0 + u1) / 2, (v0 + v1) / 2
        if not (0 <= cx < Wh and 0 <= cy < Hh) or k >= max_objs:
            continue
        _draw_gaussian(heat[c], cx, cy, w, h, heat_sigma)
        ind[k] = int(cy) * Wh + int(cx)
        wh[k] = np.log(max(w, 0.25)), np.log(max(h, 0.25))
        offset[k] = cx - int(cx), cy - int(cy)
        mask[k] = 1.0
        k += 1
    return heat, weight, ind, wh, offset, mask


def _crop(rng: np.random.Generator, img: np.ndarray, M: np.ndarray, crop: tuple[int, int]):
    """A random (W, H) window of the network-input image and M shifted to it (training patches are
    cheaper than whole frames; the network is fully convolutional, so it runs on whole frames later)."""
    W, H = crop
    h, w = img.shape[:2]
    if (W, H) == (w, h):
        return img, M
    x0, y0 = int(rng.integers(0, w - W + 1)), int(rng.integers(0, h - H + 1))
    M = M.copy()
    M[0, 2] -= x0
    M[1, 2] -= y0
    return np.ascontiguousarray(img[y0:y0 + H, x0:x0 + W]), M


#: How a vehicle cut at the picture's edge by the training augmentation (the scale jitter's placement or the
#: crop) is labelled. "half": ignored when cut to less than half its width or height (the first rounds' rule).
#: "visible": the dataset's own rule for vehicles the frame's edge cuts, which it labels as vehicles down
#: to its `min_visible_pixels`: ignored only when the vehicle's visible pixels, scaled by the share of its
#: box left inside the picture, fall below that. Under "half" a sliver of a vehicle at the edge is a
#: vehicle in the frames the network is tested on but almost never a training example.
CUT_RULES = ("half", "visible")
MIN_VISIBLE_PIXELS = 40  # `v2i dataset`'s threshold, for a dataset whose info does not record it


def min_visible_pixels(info) -> float:
    """The dataset's labelling threshold (`info.min_visible_pixels` of annotations.json, else 40), checked."""
    value = info.get("min_visible_pixels", MIN_VISIBLE_PIXELS) if isinstance(info, dict) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise ValueError(f"cut_rule 'visible' needs info.min_visible_pixels in annotations.json to be a number >= 0 "
                         f"(the dataset's labelling threshold), got {value!r}")
    return float(value)


def _cut_away(rule: str, truth: Truth, full: tuple, kept: tuple, min_visible: float) -> bool:
    """Whether a truth the augmentation cut is ignored; `full` and `kept` (x0, x1, y0, y1, network-input
    pixels): its box before and after the picture's edge cut it."""
    (a0, a1, b0, b1), (c0, c1, d0, d1) = full, kept
    if rule == "half":
        return (c1 - c0) < 0.5 * (a1 - a0) or (d1 - d0) < 0.5 * (b1 - b0)
    kept_share = (c1 - c0) * (d1 - d0) / max((a1 - a0) * (b1 - b0), 1e-9)
    if kept_share >= 1.0:
        return False
    u0, v0, u1, v1 = truth.box
    visible = truth.visible_pixels if truth.visible_pixels is not None else (u1 - u0) * (v1 - v0)
    return visible * kept_share < min_visible


def sample_item(ds: Dataset, idx: int, cfg: ModelConfig, rng: np.random.Generator, augment: bool,
                scale_jitter: float = 0.3, image: np.ndarray | None = None, crop: tuple[int, int] | None = None,
                max_occlusion: float | None = None, occluders: float = 0.0, heat_sigma: float = HEAT_SIGMA,
                cut_rule: str = "half"):
    """One training pair: network input (3, H, W) float32 and its targets. `crop` (W, H): train on a
    random window of that size of the (augmented) network-input image instead of all of it.
    `max_occlusion`: truths whose label says they are more hidden than this are ignored. `occluders`: the
    probability that a vehicle gets a painted occluder (`_occlude`; with augmentation only). `cut_rule`:
    which vehicles the jitter or the crop cuts at the picture's edge are ignored (`CUT_RULES`)."""
    s = ds.samples[idx]
    img = s.load() if image is None else image
    out, M = _geometry(rng, img, cfg, scale_jitter, augment)
    if crop is not None:
        out, M = _crop(rng, out, M, crop)
    W, H = out.shape[1], out.shape[0]
    cls = {c: i for i, c in enumerate(cfg.classes)}
    min_visible = min_visible_pixels(ds.info) if cut_rule == "visible" else 0.0
    boxes, labels, ignore = [], [], []
    for t in s.truths:
        u0, v0, u1, v1 = t.box
        p = M @ np.array([[u0, u1], [v0, v1], [1, 1]], np.float64)
        a0, a1 = sorted(p[0])
        b0, b1 = sorted(p[1])
        c0, c1, d0, d1 = max(a0, 0), min(a1, W), max(b0, 0), min(b1, H)
        if c1 - c0 < 1 or d1 - d0 < 1:
            continue
        cut = _cut_away(cut_rule, t, (a0, a1, b0, b1), (c0, c1, d0, d1), min_visible)
        boxes.append((c0, d0, c1, d1))
        labels.append(cls[t.label])
        hidden = max_occlusion is not None and t.occlusion is not None and t.occlusion > max_occlusion
        ignore.append(t.ignore or cut or hidden)
    if augment and occluders > 0:
        out = out.copy()  # never paint into a cached image
        _occlude(rng, out, boxes, ignore, occluders)
    x = (_colour(rng, out) if augment else out.astype(np.float32)) / 255.0
    tg = make_targets(np.array(boxes, np.float64).reshape(-1, 4), np.array(labels, np.int64),
                      np.array(ignore, bool), cfg, size=(W, H), heat_sigma=heat_sigma)
    return (np.ascontiguousarray(x.transpose(2, 0, 1)), *tg)


def _state_digest(state: dict) -> str:
    """sha256 over a state dict's tensors in key order (names the weights a fine-tune started from)."""
    import hashlib

    h = hashlib.sha256()
    for k in sorted(state):
        h.update(k.encode())
        h.update(state[k].detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def focal_loss(pred: torch.Tensor, gt: torch.Tensor, weight: torch.Tensor,
               class_weights: torch.Tensor | None = None) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss, normalised by the number of objects; `class_weights` (C,)
    scales each class's heatmap (its hits and its false alarms alike)."""
    pred = pred.clamp(1e-4, 1 - 1e-4)
    pos = gt.eq(1).float()
    neg = (1 - pos) * weight
    if class_weights is not None:
        cw = class_weights.view(1, -1, 1, 1)
        pos, neg = pos * cw, neg * cw
    pos_loss = torch.log(pred) * (1 - pred) ** 2 * pos
    neg_loss = torch.log(1 - pred) * pred ** 2 * (1 - gt) ** 4 * neg
    n = gt.eq(1).float().sum()
    return -(pos_loss.sum() + neg_loss.sum()) / torch.clamp(n, min=1.0)


def _gather(feat: torch.Tensor, ind: torch.Tensor) -> torch.Tensor:
    """(N, C, H, W) at flat indices (N, K) -> (N, K, C)."""
    n, c = feat.shape[:2]
    flat = feat.view(n, c, -1)
    return flat.gather(2, ind.unsqueeze(1).expand(n, c, ind.shape[1])).permute(0, 2, 1)


def loss_fn(outputs, targets, class_weights: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """Heatmap focal loss + L1 on log box size and centre offset; `class_weights` (C,) weigh each object's
    terms by its class (the class whose heatmap peaks at 1 on the object's centre cell)."""
    heat_p, size_p, off_p = outputs
    heat, weight, ind, size, offset, mask = targets
    lh = focal_loss(heat_p, heat, weight, class_weights)
    if class_weights is not None:
        own = _gather(heat, ind).ge(1.0).float()  # (N, K, C): the object's class
        mask = mask * torch.where(own.sum(2) > 0, own @ class_weights, torch.ones_like(mask))
    m = mask.unsqueeze(2)
    n = torch.clamp(targets[5].sum(), min=1.0)
    ls = (torch.abs(_gather(size_p, ind) - size) * m).sum() / (2 * n)
    lo = (torch.abs(_gather(off_p, ind) - offset) * m).sum() / (2 * n)
    total = lh + ls + lo
    return total, {"heat": lh.item(), "size": ls.item(), "offset": lo.item()}


def _dataset_problems(folder, ds: Dataset, cut_rule: str, max_occlusion: float | None) -> list[str]:
    """What makes a folder unusable for training, each naming the folder, so all are refused before any time
    is spent (not inside a batch)."""
    if len(ds) == 0:
        return [f"{folder}: the dataset has no images"]
    problems = []
    unknown = {t.label for s in ds.samples for t in s.truths} - set(ModelConfig().classes)
    if unknown:
        problems.append(f"{folder}: labels {sorted(unknown)} are not among the model's classes")
    if cut_rule == "visible":
        try:
            min_visible_pixels(ds.info)
        except ValueError as exc:
            problems.append(f"{folder}: {exc}")
    if max_occlusion is not None and all(t.occlusion is None for s in ds.samples for t in s.truths):
        problems.append(f"{folder}: max_occlusion needs occlusion labels, and this dataset has none "
                        f"(it was rendered with --no-occlusion)")
    return problems


def train(data: str | Path | Sequence[str | Path], out: str | Path | None = None, *, epochs: int = 30, seed: int = 0,
          threads: int = 2,
          batch_size: int = 8, lr: float = 2e-3, width: int = 16, input_size: tuple[int, int] = (320, 240),
          augment: bool = True, cache_images: bool = True, crop: tuple[int, int] | None = None,
          heads: str = "separable", command: str | None = None, log=None, init: str | Path | dict | None = None,
          max_occlusion: float | None = None, class_weights: dict[str, float] | None = None,
          occluders: float = 0.0, heat_sigma: float = HEAT_SIGMA, context: bool = False,
          override_input: bool = False, deep_width: int | None = None, coords: bool = False,
          cut_rule: str = "half") -> dict:
    """Train on the dataset folder `data` (or several, joined in the order given: e.g. the same scenes
    drawn by each renderer); save to `out` (if given); return the checkpoint dict.
    `crop` (W, H), multiples of 16 no larger than input_size: train on random windows of that size.
    `init`: a checkpoint to start from (its width, input size and heads are used; the arguments
    for them are then ignored). `max_occlusion` (0..1): mask truths more hidden than this. `class_weights`
    ({label: weight}, others 1): how much each class's objects count in the loss (the emergency vehicle
    is the one the case study exists for). `occluders` (0..1): the probability that a vehicle gets a painted
    occluder in a training image (`_occlude`). `heat_sigma` (0 < s <= 0.5): the heat target's spread as a
    share of a box's size; a narrower peak costs the network more for scoring cells off a long vehicle's
    centre, where a second peak becomes a second box. `context`: add the stride-32 context branch
    (`CenterNet.ctx`); with `init`, to a checkpoint without one (it starts as a no-op, see the model).
    `override_input`: with `init`, train at `input_size` instead of the checkpoint's (the network is
    fully convolutional: the same weights run at any input size, and fine-tuning adapts them to a new one).
    `deep_width`: channels at stride 16 and 32 (default 8 x width); with `init`, a checkpoint with fewer is
    widened first without changing its outputs (`model.widen`), then trained. `coords`: tell each stride-16
    cell where it is in the picture (`CenterNet.coords`; added to an `init` checkpoint, it starts as a no-op).
    `cut_rule` (one of `CUT_RULES`): which vehicles cut at the picture's edge by the augmentation are ignored."""
    if epochs < 1 or batch_size < 1 or threads < 1:
        raise ValueError(f"epochs, batch_size and threads must be >= 1, got {epochs}, {batch_size}, {threads}")
    if max_occlusion is not None and not 0.0 <= max_occlusion <= 1.0:
        raise ValueError(f"max_occlusion must be within 0..1, got {max_occlusion}")
    if not (isinstance(occluders, (int, float)) and 0.0 <= occluders <= 1.0):
        raise ValueError(f"occluders must be within 0..1, got {occluders!r}")
    if not (isinstance(heat_sigma, (int, float)) and 0.0 < heat_sigma <= 0.5):
        raise ValueError(f"heat_sigma must be within 0 < s <= 0.5 (a share of the box's size), got {heat_sigma!r}")
    if cut_rule not in CUT_RULES:
        close = difflib.get_close_matches(str(cut_rule), CUT_RULES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"cut_rule {cut_rule!r} is not one of {', '.join(CUT_RULES)}{hint}")
    class_weights = dict(class_weights or {})
    bad = [f"{k!r} (classes: {', '.join(ModelConfig().classes)})" for k in class_weights if k not in ModelConfig().classes]
    bad += [f"{k}={v!r} (must be a finite number > 0)" for k, v in class_weights.items()
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0)]
    if bad:
        raise ValueError(f"class_weights: {'; '.join(bad)}")
    base = None
    if init is not None:
        from rsu_app.perception.torch_backend import load_weights

        base_net, base = load_weights(init)  # DetectorError (a ValueError) names a bad file
        width, heads = base_net.cfg.width, base_net.cfg.heads
        input_size = input_size if override_input else base_net.cfg.input_size
        context = context or base_net.cfg.context
        coords = coords or base_net.cfg.coords
        if deep_width is not None and deep_width < base_net.cfg.deep:
            raise ValueError(f"deep_width {deep_width}: the checkpoint {init} already has {base_net.cfg.deep} "
                             f"channels at stride 16 (a network can be widened, not narrowed)")
        deep_width = deep_width or base_net.cfg.deep_width
    if crop is not None:
        crop = (int(crop[0]), int(crop[1]))
        if crop[0] % 16 or crop[1] % 16 or not (0 < crop[0] <= input_size[0] and 0 < crop[1] <= input_size[1]):
            raise ValueError(f"crop must be positive multiples of 16 within input_size {input_size}, got {crop}")
    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    folders = [data] if isinstance(data, (str, Path)) else list(data)
    sets = [load_dataset(f) for f in folders]
    problems = [p for folder, part in zip(folders, sets) for p in _dataset_problems(folder, part, cut_rule,
                                                                                   max_occlusion)]
    if problems:
        raise ValueError("; ".join(problems))
    if cut_rule == "visible" and len({min_visible_pixels(p.info) for p in sets}) > 1:
        raise ValueError(f"{', '.join(map(str, folders))}: cut_rule 'visible' needs one labelling threshold, and "
                         f"the folders' info.min_visible_pixels differ")
    ds = join_datasets(sets)
    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True)
    rng = np.random.default_rng(seed)
    cfg = ModelConfig(width=width, input_size=tuple(input_size), heads=heads, context=context, deep_width=deep_width,
                      coords=coords)
    net = CenterNet(cfg)
    if base is not None:
        # load_weights checked the checkpoint against its own config; the network differs from it at most by
        # a context branch or coordinate channels added here, which keep their no-op initial weights, and by
        # more channels at stride 16
        strict = not ((context and not base_net.cfg.context) or (coords and not base_net.cfg.coords))
        if cfg.deep > base_net.cfg.deep:
            grown = CenterNet(ModelConfig.from_dict({**base_net.cfg.to_dict(), "context": context, "coords": coords}))
            grown.load_state_dict(base["state_dict"], strict=strict)
            net.load_state_dict(widen(grown, cfg.deep, seed=seed).state_dict())
        else:
            net.load_state_dict(base["state_dict"], strict=strict)
    cw = (torch.tensor([float(class_weights.get(c, 1.0)) for c in cfg.classes]) if class_weights else None)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    steps_per_epoch = math.ceil(len(ds) / batch_size)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=epochs * steps_per_epoch,
                                                pct_start=0.15)
    images = [s.load() for s in ds.samples] if cache_images else None
    history = []
    t_start = time.perf_counter()
    net.train()
    for epoch in range(epochs):
        order = rng.permutation(len(ds))
        sums: dict[str, float] = {}
        for b in range(steps_per_epoch):
            items = [sample_item(ds, int(i), cfg, rng, augment, image=None if images is None else images[int(i)],
                                 crop=crop, max_occlusion=max_occlusion, occluders=occluders,
                                 heat_sigma=heat_sigma, cut_rule=cut_rule)
                     for i in order[b * batch_size:(b + 1) * batch_size]]
            batch = [torch.from_numpy(np.stack(col)) for col in zip(*items)]
            loss, parts = loss_fn(net(batch[0]), batch[1:], cw)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            for k, v in {"loss": loss.item(), **parts}.items():
                sums[k] = sums.get(k, 0.0) + v / steps_per_epoch
        history.append({"epoch": epoch + 1, **{k: round(v, 5) for k, v in sums.items()}})
        log(f"epoch {epoch + 1}/{epochs} " + " ".join(f"{k} {v:.4f}" for k, v in sums.items()))
    net.eval()
    ckpt = {
        "format": FORMAT,
        "config": cfg.to_dict(),
        "state_dict": {k: v.detach().clone() for k, v in net.state_dict().items()},
        "training": {
            "command": command or " ".join(sys.argv),
            "seed": seed, "epochs": epochs, "threads": threads, "batch_size": batch_size, "lr": lr,
            "augment": augment, "crop": list(crop) if crop else None, "width": width, "heads": heads,
            "input_size": list(input_size),
            "dataset": ", ".join(str(Path(f).resolve()) for f in folders), "dataset_sha256": ds.digest(),
            "datasets": [{"path": str(Path(f).resolve()), "sha256": digest, "images": len(p), "info": p.info,
                          "renderer": p.renderer} for f, p, digest in zip(folders, sets, ds.part_digests())],
            "max_occlusion": max_occlusion, "class_weights": class_weights or None, "occluders": occluders,
            "heat_sigma": heat_sigma, "context": context, "deep_width": deep_width,
            "coords": coords, "cut_rule": cut_rule,
            "init": None if base is None else {
                "command": base.get("training", {}).get("command"),
                "dataset_sha256": base.get("training", {}).get("dataset_sha256"),
                "state_sha256": _state_digest(base["state_dict"])},
            "dataset_info": ds.info, "images": len(ds),
            "annotations": sum(len(s.truths) for s in ds.samples),
            "history": history, "seconds": round(time.perf_counter() - t_start, 2),
            "torch": str(torch.__version__), "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        },
    }
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        torch.save(ckpt, out)
    return ckpt
