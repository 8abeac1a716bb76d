"""RSU perception: detect vehicles in camera frames, place them on the ground, track them.

    detector.py      Detection, the Detector interface, make_detector(name) over backends
    classical.py     OpenCV background-subtraction baseline (no learning)
    model.py         the compact CenterNet network, pre-processing and decoding
    torch_backend.py / onnx_backend.py   the learned detector on PyTorch / onnxruntime
    train.py         training on a `v2i dataset` folder
    evaluate.py      AP@0.5, AP@0.5:0.95, recall by distance and occlusion, FPS
    geo.py           box -> ground point -> WGS-84 (and back)
    tracker.py       Kalman multi-object tracker on the ground plane
    sequence.py      the whole chain on the case-study camera sequence, scored on the simulator's truth
    weights/         the shipped detector (detector.pt, detector.onnx; RECIPE.md: how it was made)
    dataset.py / synthetic.py   reading datasets / drawing a toy one for smoke tests

Heavy modules (torch, onnxruntime) are imported only by the backends that need them.
"""
from rsu_app.perception.detector import BACKENDS, Detection, Detector, DetectorError, check_frame, make_detector

__all__ = ["BACKENDS", "Detection", "Detector", "DetectorError", "check_frame", "make_detector"]
