"""The learned detector exported to ONNX and run with onnxruntime.

Why a second runtime: an RSU box may have onnxruntime (or a vendor
execution provider) but not PyTorch. The exported graph is the network
only (input: float RGB in [0, 1], (1, 3, H, W)); resizing and decoding are
the same numpy code as the torch backend, so both give the same boxes.
The model config travels in the ONNX file's metadata ("v2i_config").
"""
from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import numpy as np

from rsu_app.perception.detector import DEFAULT_THREADS, Detection, DetectorError, check_frame, default_weights
from rsu_app.perception.model import ModelConfig, decode, preprocess

OUTPUTS = ("heat", "size", "offset")


def export_onnx(weights, path: str | Path | None = None, opset: int = 17) -> bytes:
    """Export a checkpoint (path or dict) to ONNX; write it to `path` if given; return the bytes."""
    import onnx
    import torch

    from rsu_app.perception.torch_backend import load_weights

    net, ckpt = load_weights(weights)
    W, H = net.cfg.input_size
    buf = io.BytesIO()
    # the TorchScript exporter: the dynamo one needs onnxscript, which the project does not install
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", (DeprecationWarning, FutureWarning, UserWarning))
        torch.onnx.export(net, (torch.zeros(1, 3, H, W),), buf, input_names=["image"], output_names=list(OUTPUTS),
                          opset_version=opset, dynamo=False, do_constant_folding=True)
    model = onnx.load_from_string(buf.getvalue())
    meta = {"v2i_config": json.dumps(net.cfg.to_dict()),
            "v2i_training": json.dumps({k: v for k, v in ckpt.get("training", {}).items() if k != "history"})}
    for k, v in meta.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, v
    data = model.SerializeToString()
    if path is not None:
        Path(path).write_bytes(data)
    return data


class OnnxDetector:
    name = "onnx"

    def __init__(self, weights: str | Path | bytes | None = None, *, threads: int = DEFAULT_THREADS,
                 score_threshold: float = 0.3,
                 top_k: int = 50, providers: list[str] | None = None):
        """`weights`: an .onnx file (or its bytes), or a torch checkpoint (.pt), exported on the fly;
        default the shipped weights/detector.onnx."""
        import onnxruntime as ort

        if weights is None:
            weights = default_weights("onnx")
        if isinstance(weights, (str, Path)):
            p = Path(weights)
            if not p.is_file():
                raise DetectorError(f"weights file not found: {p}")
            data = export_onnx(p) if p.suffix in (".pt", ".pth") else p.read_bytes()
        else:
            data = bytes(weights)
        opts = ort.SessionOptions()
        if not isinstance(threads, int) or threads < 1:
            raise DetectorError(f"threads must be an integer >= 1, got {threads!r}")
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        self.threads = threads
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        if providers is None:
            avail = ort.get_available_providers()
            providers = [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in avail]
        try:
            self.session = ort.InferenceSession(data, sess_options=opts, providers=providers)
        except Exception as exc:  # onnxruntime raises its own exception types
            raise DetectorError(f"onnx detector: cannot load the model ({exc})") from exc
        meta = self.session.get_modelmeta().custom_metadata_map
        if "v2i_config" not in meta:
            raise DetectorError("onnx detector: the model has no 'v2i_config' metadata (not exported by export_onnx)")
        self.cfg = ModelConfig.from_dict(json.loads(meta["v2i_config"]))
        self.score_threshold, self.top_k = score_threshold, top_k

    def raw(self, rgb: np.ndarray):
        x, scale = preprocess(check_frame(rgb), self.cfg)
        heat, size, off = self.session.run(list(OUTPUTS), {"image": x})
        return heat, size, off, scale

    def detect(self, rgb: np.ndarray) -> list[Detection]:
        heat, size, off, scale = self.raw(rgb)
        return [Detection((u0, v0, u1, v1), label, score) for u0, v0, u1, v1, label, score in
                decode(heat, size, off, scale, self.cfg.stride, self.cfg.classes, self.score_threshold, self.top_k)]
