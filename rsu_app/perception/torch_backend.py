"""The learned detector on PyTorch (CUDA when present, else CPU with a set number of threads)."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch

from bridges.allocator import keep_freed_memory
from rsu_app.perception.detector import DEFAULT_THREADS, Detection, DetectorError, check_frame, default_weights
from rsu_app.perception.model import FORMAT, CenterNet, ModelConfig, decode, fuse_for_inference, preprocess


def load_weights(weights: str | Path | dict) -> tuple[CenterNet, dict]:
    """A checkpoint written by `train` -> the network in eval mode and the checkpoint dict."""
    if isinstance(weights, dict):
        ckpt = weights
    else:
        path = Path(weights)
        if not path.is_file():
            raise DetectorError(f"weights file not found: {path}")
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises many kinds for a corrupt or foreign file
            raise DetectorError(f"{path}: not a detector checkpoint ({exc})") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise DetectorError(f"weights: expected a {FORMAT!r} checkpoint, got format "
                            f"{ckpt.get('format') if isinstance(ckpt, dict) else type(ckpt).__name__!r}")
    name = "weights" if isinstance(weights, dict) else str(weights)
    try:
        net = CenterNet(ModelConfig.from_dict(ckpt["config"]))
    except (AttributeError, KeyError, TypeError, ValueError) as exc:  # a hand-edited or foreign config: say which file and key
        what = f"no {exc}" if isinstance(exc, KeyError) else str(exc)
        raise DetectorError(f"{name}: the checkpoint's config does not describe a network: {what}") from None
    state, own = ckpt["state_dict"], net.state_dict()
    problems = {"missing": [k for k in own if k not in state],
                "unexpected": [k for k in state if k not in own],
                "of another shape": [f"{k} {tuple(v.shape)} (the network's: {tuple(own[k].shape)})"
                                     for k, v in state.items() if k in own and tuple(v.shape) != tuple(own[k].shape)]}
    if any(problems.values()):
        listed = [f"{len(v)} {what} ({', '.join(v[:3])}{', ...' if len(v) > 3 else ''})"
                  for what, v in problems.items() if v]
        raise DetectorError(f"{name}: the weights do not fit the network their config describes: " + "; ".join(listed))
    net.load_state_dict(state)
    return net.eval(), ckpt


def compile_network(net: CenterNet, device: torch.device) -> torch.nn.Module:
    """`net` through torch.compile (TorchInductor), compiled here on a blank input rather than on the first
    camera frame.

    Why opt-in (`compile=True`, the RSU app's `detector.compile`): on one CPU core the compiled network runs
    about 1.15x faster than the eager one (medians; benchmarks/perception.py measures both, and the outputs
    are the eager ones; it was 1.4-1.6x while the eager one still had glibc map its buffers afresh every
    frame, bridges/allocator.py), but compiling takes seconds when the detector is built (tens of seconds the
    first time on a machine, a few from inductor's on-disk cache after) and needs a C++ compiler at run
    time, which a deployed box may not have."""
    W, H = net.cfg.input_size
    try:
        with warnings.catch_warnings(), torch.inference_mode():
            # torch's compiler imports parts of itself that use its deprecated torch.jit: its warning, not ours
            warnings.filterwarnings("ignore", message=r"`torch\.jit\.", category=DeprecationWarning)
            fast = torch.compile(net, dynamic=False)
            fast(torch.zeros(1, 3, H, W, device=device))
    except Exception as exc:  # inductor raises many kinds (no compiler, unsupported platform)
        raise DetectorError(f"torch.compile could not compile the network ({type(exc).__name__}: "
                            f"{str(exc).strip().splitlines()[0] if str(exc).strip() else 'no message'}); on a CPU it "
                            f"needs a C++ compiler: run without compile, or use the onnx backend") from exc
    return fast


class TorchDetector:
    name = "torch"

    def __init__(self, weights: str | Path | dict | None = None, *, device: str = "auto", threads: int = DEFAULT_THREADS,
                 score_threshold: float = 0.3, top_k: int = 50, random_weights: bool = False,
                 config: ModelConfig | None = None, compile: bool = False):
        if weights is None and not random_weights:
            weights = default_weights("torch")  # the shipped weights
        if weights is not None:
            self.net, self.checkpoint = load_weights(weights)
        else:
            torch.manual_seed(0)
            self.net, self.checkpoint = CenterNet(config or ModelConfig()).eval(), None
        self.net = fuse_for_inference(self.net)  # same outputs to float rounding, faster on a CPU (its docstring)
        self.cfg = self.net.cfg
        if not isinstance(threads, int) or threads < 1:
            raise DetectorError(f"threads must be an integer >= 1, got {threads!r}")
        torch.set_num_threads(threads)  # process-wide: torch has no per-module thread count
        keep_freed_memory()  # process-wide too: a frame's feature maps reused, not mapped afresh (its docstring)
        self.threads = threads
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() else "cpu"
        self.device = torch.device(device)
        self.net.to(self.device)
        self.compiled = bool(compile)
        if compile:
            self.net = compile_network(self.net, self.device)
        self.score_threshold, self.top_k = score_threshold, top_k

    @torch.inference_mode()
    def raw(self, rgb: np.ndarray):
        x, scale = preprocess(check_frame(rgb), self.cfg)
        heat, size, off = self.net(torch.from_numpy(x).to(self.device))
        return heat.cpu().numpy(), size.cpu().numpy(), off.cpu().numpy(), scale

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        heat, size, off, scale = self.raw(rgb)
        return [Detection((u0, v0, u1, v1), label, score) for u0, v0, u1, v1, label, score in
                decode(heat, size, off, scale, self.cfg.stride, self.cfg.classes, self.score_threshold, self.top_k)]
