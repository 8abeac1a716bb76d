"""The Detector interface: backend table, input checks, and the classical baseline on rendered frames."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import has_cxx_compiler

from rsu_app.perception import Detection, DetectorError, make_detector
from rsu_app.perception.evaluate import iou_matrix

pytest.importorskip("pybullet")


def test_unknown_backend_lists_known():
    with pytest.raises(DetectorError, match="unknown detector 'yolo'; known: classical, onnx, torch"):
        make_detector("yolo")


@pytest.mark.parametrize("backend,options,match", [
    ("onnx", {"compile": True}, r"detector 'onnx' does not take option 'compile'; it takes: weights, threads"),
    ("torch", {"thread": 1}, r"'thread' \(did you mean 'threads'\?\)"),
    ("classical", {"weights": "w.pt", "thresh": 3},
     r"does not take options 'weights', 'thresh' \(did you mean 'threshold'\?\); it takes: background"),
])
def test_an_option_the_backend_does_not_take_is_named(backend, options, match):
    """Backends take different options; one a backend does not take is a DetectorError naming each (with a
    "did you mean") and what the backend takes, raised before anything is loaded, not a bare TypeError."""
    with pytest.raises(DetectorError, match=match):
        make_detector(backend, **options)


@pytest.mark.parametrize("frame,match", [
    ([[1, 2, 3]], "numpy array"),
    (np.zeros((48, 64), np.uint8), r"shape \(H, W, 3\)"),
    (np.zeros((48, 64, 4), np.uint8), r"shape \(H, W, 3\)"),
    (np.zeros((0, 64, 3), np.uint8), "empty"),
    (np.zeros((48, 64, 3), np.float32), "uint8"),
])
@pytest.mark.parametrize("backend", ["classical", "torch"])
def test_bad_frames_are_named(backend, frame, match):
    opts = {"random_weights": True, "threads": 1} if backend == "torch" else {}
    det = make_detector(backend, **opts)
    with pytest.raises(DetectorError, match=match):
        det.detect(frame)


@pytest.mark.parametrize("kw,match", [
    (dict(box=(0, 0, math.nan, 1), label="car", score=1.0), "finite"),
    (dict(box=(5, 0, 1, 1), label="car", score=1.0), "u1 >= u0"),
    (dict(box=(0, 0, 1, 1), label="bus", score=1.0), "label"),
])
def test_detection_checks(kw, match):
    with pytest.raises(DetectorError, match=match):
        Detection(**kw)


def test_torch_defaults_to_shipped_weights_and_says_when_they_are_missing(monkeypatch, tmp_path):
    from rsu_app.perception import detector as detmod

    with pytest.raises(DetectorError, match="not found"):
        make_detector("torch", weights="/nonexistent/w.pt")
    monkeypatch.setitem(detmod.DEFAULT_WEIGHTS, "torch", tmp_path / "none.pt")
    monkeypatch.setitem(detmod.DEFAULT_WEIGHTS, "onnx", tmp_path / "none.onnx")
    with pytest.raises(DetectorError, match="no shipped weights"):
        make_detector("torch")
    with pytest.raises(DetectorError, match="no shipped weights"):
        make_detector("onnx")


def test_random_weights_find_nothing_in_a_blank_frame():
    det = make_detector("torch", random_weights=True, threads=1)
    assert det.detect(np.full((480, 640, 3), 90, np.uint8)) == []


@pytest.fixture(scope="module")
def rendered():
    """The case-study camera: an empty frame, and one with a car and the emergency vehicle."""
    from master.world.ground_truth import frame_truth
    from master.world.layout import Building, CameraSpec, VehicleSpec, WorldLayout
    from master.world.world import World

    cam = CameraSpec("rsu_cam", 6.5, 6.5, 6.0, yaw=225.0, pitch=-14.0, width=640, height=480, fov_deg=100.0)
    layout = WorldLayout(buildings=[Building("sw", -30, -30, 48, 48, 15)], cameras=[cam], vehicles={
        "car": VehicleSpec("car", 4.5, 1.8, 1.5, (0.1, 0.3, 0.85)),
        "ev": VehicleSpec("ev", 6.5, 2.3, 2.6, (0.9, 0.08, 0.08), kind="emergency", rear_overhang=1.42)})
    with World(layout) as w:
        c = w.cameras["rsu_cam"]
        empty = c.render()
        w.pose_vehicle("car", 1.75, -15.0, math.pi / 2)
        w.pose_vehicle("ev", -20.0, -1.75, 0.0)
        frame = c.render()
        truth = {t.name: t for t in frame_truth(w.scene, c, frame, occlusion=False)}
    return empty.rgb, frame.rgb, truth


def test_classical_finds_both_vehicles_with_labels(rendered):
    empty, frame, truth = rendered
    det = make_detector("classical", background=empty)
    assert det.detect(empty) == []  # no vehicles, no boxes
    found = det.detect(frame)
    assert len(found) == 2, found
    for name, label in (("car", "car"), ("ev", "emergency")):
        box = truth[name].visible_box
        best = max(found, key=lambda d: iou_matrix([d.box], [box])[0, 0])
        assert iou_matrix([best.box], [box])[0, 0] > 0.85 and best.label == label, (best, box)
        assert 0 < best.score <= 1


def test_classical_mog2_learns_the_background(rendered):
    empty, frame, _ = rendered
    det = make_detector("classical")
    for _ in range(30):
        det.detect(empty)
    assert len(det.detect(frame)) == 2


def test_classical_background_shape_mismatch(rendered):
    empty, _, _ = rendered
    det = make_detector("classical", background=empty)
    with pytest.raises(DetectorError, match="differs from the background"):
        det.detect(np.zeros((240, 320, 3), np.uint8))
    with pytest.raises(DetectorError, match="cannot read background"):
        make_detector("classical", background="/nonexistent.png")


def _heat_with_peaks(peaks, shape=(2, 30, 40)):
    """Network outputs with isolated unit peaks: (class, row, col, score, log w, log h) each."""
    heat = np.zeros((1, *shape), np.float32)
    size = np.zeros((1, 2, *shape[1:]), np.float32)
    off = np.zeros((1, 2, *shape[1:]), np.float32)
    for c, y, x, score, lw, lh in peaks:
        heat[0, c, y, x] = score
        size[0, :, y, x] = lw, lh
    return heat, size, off


def test_decode_box_nms_drops_a_second_peak_on_the_same_vehicle():
    """Two peaks 3 cells apart with the same large box (a long vehicle), and a car and an emergency peak
    on one vehicle, each give one box, the higher-scored; a separate vehicle keeps its box; with
    nms_iou=None all four peaks come out."""
    from rsu_app.perception.model import decode

    big, small = np.log(12.0), np.log(4.0)
    heat, size, off = _heat_with_peaks([(0, 10, 10, 0.9, big, big), (0, 10, 13, 0.6, big, big),
                                        (1, 20, 30, 0.7, small, small), (0, 20, 30, 0.5, small, small)])
    out = decode(heat, size, off, (2.0, 2.0), 4, ("car", "emergency"), score_threshold=0.3)
    assert [(lab, round(s, 2)) for *_, lab, s in out] == [("car", 0.9), ("emergency", 0.7)]
    raw = decode(heat, size, off, (2.0, 2.0), 4, ("car", "emergency"), score_threshold=0.3, nms_iou=None)
    assert len(raw) == 4
    # boxes that only touch are different vehicles
    heat, size, off = _heat_with_peaks([(0, 10, 10, 0.9, small, small), (0, 10, 14, 0.8, small, small)])
    assert len(decode(heat, size, off, (1.0, 1.0), 4, ("car", "emergency"))) == 2


def test_learned_backends_default_to_one_thread_and_refuse_bad_counts():
    """One thread unless told: the master, renderer and app share 2 cores (benchmarks/perception.py)."""
    import torch

    from rsu_app.perception.detector import DEFAULT_THREADS

    assert DEFAULT_THREADS == 1
    torch.set_num_threads(2)
    det = make_detector("torch")
    assert det.threads == 1 and torch.get_num_threads() == 1
    assert make_detector("onnx").threads == 1
    for backend in ("torch", "onnx"):
        for bad in (0, -1, 1.5, None):
            with pytest.raises(DetectorError, match="threads must be an integer >= 1"):
                make_detector(backend, threads=bad)


def test_torch_backend_on_cpu_when_asked_and_auto_without_cuda():
    import torch

    rgb = np.full((480, 640, 3), 128, np.uint8)
    cpu = make_detector("torch", device="cpu")
    assert cpu.device.type == "cpu" and isinstance(cpu.detect(rgb), list)
    auto = make_detector("torch")
    assert auto.device.type == ("cuda" if torch.cuda.is_available() else "cpu")


@pytest.mark.skipif(not __import__("torch").cuda.is_available(),
                    reason="no CUDA device on this machine: the torch backend's GPU path cannot run here")
def test_torch_on_cuda_finds_the_cpu_boxes(rendered):
    _, rgb, _ = rendered
    cpu, gpu = make_detector("torch", device="cpu"), make_detector("torch", device="cuda")
    dc, dg = cpu.detect(rgb), gpu.detect(rgb)
    assert dc and [d.label for d in dc] == [d.label for d in dg]
    assert np.allclose([d.box for d in dc], [d.box for d in dg], atol=0.5)


@pytest.mark.skipif(not has_cxx_compiler(),
                    reason="no C++ compiler on this machine: torch.compile cannot build the network's CPU code")
def test_the_compiled_torch_network_finds_the_eager_boxes(rendered):
    """`compile=True` runs the network through torch.compile, compiled when the detector is built (not on the
    first frame); same boxes, labels and scores as the eager network on the case-study frame."""
    _, rgb, truth = rendered
    eager, fast = make_detector("torch", threads=1), make_detector("torch", threads=1, compile=True)
    assert fast.compiled and not eager.compiled and fast.cfg == eager.cfg
    de, df = eager.detect(rgb), fast.detect(rgb)
    assert {d.label for d in de if d.score > 0.5} == {"car", "emergency"}
    assert [d.label for d in de] == [d.label for d in df]
    assert np.allclose([d.box for d in de], [d.box for d in df], atol=0.05)
    assert np.allclose([d.score for d in de], [d.score for d in df], atol=1e-4)


def test_a_network_that_does_not_compile_is_a_detector_error(monkeypatch):
    """Without a working C++ toolchain inductor fails inside the first call; the detector says what to do."""
    import torch

    def broken(net, **kw):
        def call(x):
            raise RuntimeError("InductorError: CppCompileError: C++ compile error\nmore")
        return call

    monkeypatch.setattr(torch, "compile", broken)
    with pytest.raises(DetectorError, match=r"could not compile the network \(RuntimeError: InductorError: "
                                            r"CppCompileError: C\+\+ compile error\).*onnx backend"):
        make_detector("torch", threads=1, compile=True)
