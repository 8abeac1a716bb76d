"""A compact CenterNet-style detector: one heatmap per class, box size and centre offset.

Why this shape: the RSU camera is static and vehicles are few, small and
axis-aligned in the image, so an anchor-free single-stage detector with a
stride-4 output is enough and runs at camera rate on a couple of CPU cores.
The network is resolution-agnostic; `ModelConfig.input_size` fixes the
resolution frames are resized to before inference (640x480 -> 320x240 by
default). Decoding (peak picking, top-k) is plain numpy so that the torch
and onnx backends share it bit for bit.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
import torch
from torch import nn

CLASSES = ("car", "emergency")
FORMAT = "v2i-centernet/1"  # checkpoint format tag, bumped when the layout changes
HEADS = ("separable", "conv")  # output-head block kinds (ModelConfig.heads)
NMS_IOU = 0.5  # decode's class-agnostic box NMS: boxes overlapping a better one by more are the same vehicle


@dataclass
class ModelConfig:
    width: int = 16                      # channels of the first stage; later stages are multiples
    input_size: tuple[int, int] = (320, 240)  # (W, H) the frame is resized to
    classes: tuple[str, ...] = CLASSES
    heads: str = "separable"             # head blocks: "separable" (depthwise 3x3 + 1x1) or "conv" (full 3x3)
    context: bool = False                # a stride-32 context branch (CenterNet.ctx) widens what each cell sees
    deep_width: int | None = None        # channels at stride 16 and 32 (None: 8 x width); see CenterNet
    coords: bool = False                 # tell each stride-16 cell where it is in the picture (CenterNet.coords)
    stride: int = field(default=4, init=False)  # output stride (fixed by the architecture)

    def __post_init__(self):
        W, H = self.input_size
        if W % 16 or H % 16 or W <= 0 or H <= 0:
            raise ValueError(f"input_size must be positive multiples of 16 (the network's coarsest stride), "
                             f"got {W}x{H}")
        if self.width < 1 or not self.classes:
            raise ValueError(f"width must be >= 1 and classes non-empty, got {self.width}, {self.classes}")
        if self.heads not in HEADS:
            raise ValueError(f"heads must be one of {sorted(HEADS)}, got {self.heads!r}")
        if self.deep_width is not None and (not isinstance(self.deep_width, int) or self.deep_width < 8 * self.width):
            raise ValueError(f"deep_width must be an integer >= 8 x width ({8 * self.width}), got {self.deep_width!r}")

    @property
    def deep(self) -> int:
        """Channels of the stride-16 stage and the context branch."""
        return self.deep_width or 8 * self.width

    def to_dict(self) -> dict:
        d = asdict(self)
        d["input_size"], d["classes"] = list(self.input_size), list(self.classes)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        # checkpoints written before `heads` existed used full 3x3 convolutions
        # and those written before `context` existed had no context branch
        deep = d.get("deep_width")
        return cls(width=int(d["width"]), input_size=tuple(int(x) for x in d["input_size"]),
                   classes=tuple(d["classes"]), heads=str(d.get("heads", "conv")),
                   context=bool(d.get("context", False)), deep_width=None if deep is None else int(deep),
                   coords=bool(d.get("coords", False)))


def _conv(cin: int, cout: int, k: int = 3, s: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, k, s, k // 2, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


def _dw(cin: int, cout: int, s: int = 1) -> nn.Sequential:
    """Depthwise-separable block: cheap spatial mixing, then a pointwise channel mix."""
    return nn.Sequential(nn.Conv2d(cin, cin, 3, s, 1, groups=cin, bias=False), nn.BatchNorm2d(cin),
                         nn.ReLU(inplace=True), _conv(cin, cout, 1))


def _head(c: int, n_out: int, kind: str) -> nn.Sequential:
    """One output head at stride 4. The heads run on the most cells of the network, so at larger
    input sizes the depthwise-separable form is what keeps the detector at camera rate."""
    block = _dw(c, c) if kind == "separable" else _conv(c, c)
    return nn.Sequential(block, nn.Conv2d(c, n_out, 1))



def picture_grid(f: torch.Tensor) -> torch.Tensor:
    """(1, 2, h, w): each cell's centre as (x, y) in -1..1 over a feature map `f` (N, C, h, w), left/top -1."""
    h, w = f.shape[-2:]
    xs = (torch.arange(w, dtype=f.dtype, device=f.device) + 0.5) * (2.0 / w) - 1.0
    ys = (torch.arange(h, dtype=f.dtype, device=f.device) + 0.5) * (2.0 / h) - 1.0
    return torch.stack([xs.view(1, w).expand(h, w), ys.view(h, 1).expand(h, w)]).unsqueeze(0)


class CenterNet(nn.Module):
    """Input: float RGB in [0, 1], (N, 3, H, W), H and W multiples of 16.
    Outputs at stride 4: heat (N, C, H/4, W/4) after sigmoid, size (N, 2, ..) as log(w, h) in
    output cells, offset (N, 2, ..) of the centre within its cell."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        c = cfg.width
        self.cfg = cfg
        self.stem = nn.Sequential(_conv(3, c, 3, 2), _dw(c, c))                 # /2
        self.s4 = nn.Sequential(_dw(c, 2 * c, 2), _dw(2 * c, 2 * c))            # /4
        self.s8 = nn.Sequential(_dw(2 * c, 4 * c, 2), _dw(4 * c, 4 * c))        # /8
        # Why `deep_width`: at 1/256 of the input's cells the stride-16 and -32 layers are the cheapest place
        # to add channels (`widen` grows a trained network there without changing its outputs). Measured so
        # far (RECIPE.md, stages 10 and 11): 256 instead of 128 fits the training frames better, not new ones
        d = cfg.deep
        self.s16 = nn.Sequential(_dw(4 * c, d, 2), _dw(d, d), _dw(d, d))  # /16
        if cfg.context:
            # Why: without it a stride-4 cell sees about 140 input pixels, less than a near emergency
            # vehicle's length (300-500 px in the frame), so each end of it can look like a centre. The
            # branch ends in a zero-initialised 1x1 convolution: added to a trained network it changes
            # nothing until fine-tuning teaches it something (`train --init ... --context`).
            self.ctx = nn.Sequential(_dw(d, d, 2), _dw(d, d), nn.Conv2d(d, d, 1))  # /32
            nn.init.zeros_(self.ctx[-1].weight)
            nn.init.zeros_(self.ctx[-1].bias)
        if cfg.coords:
            # Why: a truth is the visible box, so a near vehicle cut by the picture's border has a size target
            # that ends there, and a cell at the centre of a box 300 px wide cannot see (at stride 4) how far
            # the border is: its boxes come out short. Two channels, x and y in -1..1 over the network input,
            # mixed in by a 1x1 convolution before the context branch; zero-initialised like it, so added to
            # a trained network it changes nothing until fine-tuning (`train --init ... --coords`). Measured
            # (RECIPE.md, sixth round): fine-tuned on stage 9 it left these weights near zero, and neither the
            # border boxes nor AP moved against the same training without it
            self.coords = nn.Conv2d(2, d, 1)
            nn.init.zeros_(self.coords.weight)
            nn.init.zeros_(self.coords.bias)
        self.lat16 = _conv(d, 2 * c, 1)
        self.lat8 = _conv(4 * c, 2 * c, 1)
        self.fuse = _dw(2 * c, 2 * c)
        n = len(cfg.classes)
        self.heat = _head(2 * c, n, cfg.heads)
        self.size = _head(2 * c, 2, cfg.heads)
        self.offset = _head(2 * c, 2, cfg.heads)
        # focal-loss prior: start with ~1% foreground so early training is stable
        nn.init.constant_(self.heat[-1].bias, -4.6)
        self.register_buffer("mean", torch.tensor([0.45, 0.45, 0.45]).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor([0.25, 0.25, 0.25]).view(1, 3, 1, 1))

    def forward(self, x: torch.Tensor):
        x = (x - self.mean) / self.std
        f4 = self.s4(self.stem(x))
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        if self.cfg.coords:
            f16 = f16 + self.coords(picture_grid(f16))
        if self.cfg.context:
            f16 = f16 + nn.functional.interpolate(self.ctx(f16), size=f16.shape[-2:], mode="nearest")
        up = nn.functional.interpolate(self.lat16(f16), scale_factor=2.0, mode="nearest") + self.lat8(f8)
        f = self.fuse(nn.functional.interpolate(up, scale_factor=2.0, mode="nearest") + f4)
        return torch.sigmoid(self.heat(f)), self.size(f), self.offset(f)


def widen(net: CenterNet, deep_width: int, seed: int = 0, noise: float = 1e-3) -> CenterNet:
    """A copy of `net` (eval or train mode alike) with `deep_width` channels at stride 16 and 32, computing
    the same outputs (to `noise`), so that fine-tuning starts from what `net` learnt (Net2Net's widening).

    Each new channel copies an existing one (chosen with `seed`): its incoming weights and BatchNorm
    statistics are the copied channel's, and every layer reading the widened channels divides the weights
    it applies to a channel and its copies by how many there are, so their sum is what the one channel
    gave. Copies with identical weights would get identical gradients and never become different
    features: the copies' incoming weights get relative noise of `noise` (0: exact)."""
    old = net.cfg.deep
    if deep_width < old:
        raise ValueError(f"widen: deep_width {deep_width} is narrower than the network's {old}")
    cfg = ModelConfig.from_dict({**net.cfg.to_dict(), "deep_width": deep_width})
    big = CenterNet(cfg)
    gen = torch.Generator().manual_seed(seed)
    pick = torch.cat([torch.arange(old), torch.randint(0, old, (deep_width - old,), generator=gen)])
    copies = torch.bincount(pick, minlength=old).float()[pick]  # how many channels share each one's source
    state = {}
    for key, v in net.state_dict().items():
        target = big.state_dict()[key]
        if v.shape == target.shape:
            state[key] = v.clone()
            continue
        w = v
        if w.ndim >= 1 and w.shape[0] == old and target.shape[0] == deep_width:  # the channels a layer makes
            w = w[pick].clone()
            if w.ndim == 4 and noise:
                fresh = torch.arange(deep_width) >= old
                scale = w[fresh].abs().mean().clamp(min=1e-12)
                w[fresh] += noise * scale * torch.randn(w[fresh].shape, generator=gen)
        if w.ndim == 4 and w.shape[1] == old and target.shape[1] == deep_width:  # the channels a layer reads
            w = w[:, pick] / copies.view(1, -1, 1, 1)
        state[key] = w
    big.load_state_dict(state)
    return big.train(net.training)


def fuse_for_inference(net: CenterNet) -> CenterNet:
    """Fold every BatchNorm into the convolution before it and keep the weights channels-last, in place.

    Why: at batch 1 on a CPU core, most of this small network's time is memory traffic, not
    arithmetic; a separate BatchNorm pass over every feature map doubles it, and PyTorch's
    depthwise and pointwise convolutions run faster on channels-last tensors once no BatchNorm
    (slow in that layout) sits between them. Measured on this project's 2-core machine: the
    network alone 1.35-1.45x faster at 512x384 (benchmarks/perception.py, alternating runs).
    The outputs match the unfused network's to float rounding (1e-6 to 1e-4: the fold reorders
    the arithmetic). Inference only: a fused network has no BatchNorm statistics left to train."""
    if net.training:
        raise ValueError("fuse_for_inference: the network is in training mode; call .eval() first "
                         "(fusion bakes in the BatchNorm running statistics)")
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    for block in net.modules():
        if isinstance(block, nn.Sequential):
            for i in range(len(block) - 1):
                if isinstance(block[i], nn.Conv2d) and isinstance(block[i + 1], nn.BatchNorm2d):
                    block[i] = fuse_conv_bn_eval(block[i], block[i + 1])
                    block[i + 1] = nn.Identity()
    return net.to(memory_format=torch.channels_last)


def preprocess(rgb: np.ndarray, cfg: ModelConfig) -> tuple[np.ndarray, tuple[float, float]]:
    """uint8 HxWx3 frame -> float32 (1, 3, h, w) network input and the (sx, sy) scale back to the frame."""
    W, H = cfg.input_size
    h0, w0 = rgb.shape[:2]
    img = rgb if (w0, h0) == (W, H) else cv2.resize(rgb, (W, H), interpolation=cv2.INTER_AREA)
    x = np.ascontiguousarray(img.transpose(2, 0, 1)[None], dtype=np.float32)
    x *= 1.0 / 255.0
    return x, (w0 / W, h0 / H)


def box_nms(boxes: np.ndarray, iou: float) -> np.ndarray:
    """Indices of `boxes` (N, 4; sorted by falling score) kept by greedy non-maximum suppression."""
    keep: list[int] = []
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    for i in range(len(boxes)):
        if keep:
            k = np.array(keep)
            iw = np.clip(np.minimum(boxes[k, 2], boxes[i, 2]) - np.maximum(boxes[k, 0], boxes[i, 0]), 0, None)
            ih = np.clip(np.minimum(boxes[k, 3], boxes[i, 3]) - np.maximum(boxes[k, 1], boxes[i, 1]), 0, None)
            inter = iw * ih
            if np.any(inter > iou * (area[k] + area[i] - inter)):
                continue
        keep.append(i)
    return np.array(keep, int)


def decode(heat: np.ndarray, size: np.ndarray, offset: np.ndarray, scale: tuple[float, float], stride: int,
           classes: tuple[str, ...], score_threshold: float = 0.3, top_k: int = 50, nms_iou: float | None = NMS_IOU):
    """Network outputs of one image -> list of (u0, v0, u1, v1, label, score) in frame pixels.

    Peaks are cells that equal the max of their 3x3 neighbourhood of the same class (the CenterNet
    NMS). That leaves a second peak on a long vehicle, or one per class on the same vehicle, so
    the boxes then go through class-agnostic box NMS at `nms_iou` (None: off)."""
    heat = heat[0]
    peaks = np.empty_like(heat)
    kernel = np.ones((3, 3), np.uint8)
    for c in range(heat.shape[0]):
        peaks[c] = cv2.dilate(heat[c], kernel)
    cand = np.flatnonzero((heat == peaks) & (heat >= score_threshold))
    if len(cand) == 0:
        return []
    scores = heat.reshape(-1)[cand]
    order = np.argsort(-scores, kind="stable")[:top_k]
    cand, scores = cand[order], scores[order]
    C, Hh, Wh = heat.shape
    cls, rem = np.divmod(cand, Hh * Wh)
    ys, xs = np.divmod(rem, Wh)
    ox, oy = offset[0, 0, ys, xs], offset[0, 1, ys, xs]
    bw, bh = np.exp(np.clip(size[0, 0, ys, xs], -4, 6)), np.exp(np.clip(size[0, 1, ys, xs], -4, 6))
    cx, cy = (xs + ox) * stride * scale[0], (ys + oy) * stride * scale[1]
    bw, bh = bw * stride * scale[0], bh * stride * scale[1]
    boxes = np.column_stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2])
    keep = box_nms(boxes, nms_iou) if nms_iou is not None else range(len(cand))
    return [(*(float(b) for b in boxes[i]), classes[int(cls[i])], float(scores[i])) for i in keep]
