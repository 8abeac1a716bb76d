"""Training, checkpoints, ONNX export and the CLI on a toy dataset drawn with OpenCV."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from rsu_app.perception import DetectorError, make_detector
from rsu_app.perception.dataset import DatasetError, join_datasets, load_dataset
from rsu_app.perception.evaluate import evaluate
from rsu_app.perception.model import ModelConfig
from rsu_app.perception.synthetic import write_dataset
from rsu_app.perception.train import _geometry, train

torch.set_num_threads(1)
TINY = dict(threads=1, width=8, input_size=(192, 144), batch_size=4, log=lambda m: None)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_dataset(tmp_path_factory.mktemp("toy"), n_images=12, seed=3, max_vehicles=2)


@pytest.fixture(scope="module")
def learnt(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("w") / "w.pt"
    ckpt = train(data, out, epochs=40, seed=0, augment=False, lr=4e-3, **TINY)
    return out, ckpt


def test_learns_the_toy_set_and_reports_metadata(data, learnt):
    out, ckpt = learnt
    hist = ckpt["training"]["history"]
    assert hist[-1]["loss"] < 0.2 * hist[0]["loss"]
    det = make_detector("torch", weights=out, threads=1, score_threshold=0.1)
    rep = evaluate(det, load_dataset(data))
    assert rep.ap50["car"] > 0.9 and rep.ap50["emergency"] > 0.9, rep.table()
    empty = [s for s in load_dataset(data).samples if not s.truths]
    assert empty and all(det.detect(s.load()) == [] for s in empty)  # no vehicles, no boxes
    tr = ckpt["training"]
    assert tr["seed"] == 0 and len(tr["dataset_sha256"]) == 64 and tr["images"] == 12 and tr["command"]
    assert out.stat().st_size < 3_000_000


def test_same_seed_same_weights_other_seed_differs(data):
    a = train(data, None, epochs=1, seed=5, **TINY)["state_dict"]
    b = train(data, None, epochs=1, seed=5, **TINY)["state_dict"]
    c = train(data, None, epochs=1, seed=6, **TINY)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_onnx_matches_torch(learnt, data, tmp_path):
    from rsu_app.perception.onnx_backend import export_onnx

    out, _ = learnt
    onnx_path = tmp_path / "w.onnx"
    export_onnx(out, onnx_path)
    t = make_detector("torch", weights=out, threads=1, score_threshold=0.1)
    o = make_detector("onnx", weights=onnx_path, threads=1, score_threshold=0.1)
    for s in load_dataset(data).samples[:4]:
        rgb = s.load()
        rt, ro = t.raw(rgb), o.raw(rgb)
        assert all(np.abs(x - y).max() < 1e-4 for x, y in zip(rt[:3], ro[:3]))
        dt, do = t.detect(rgb), o.detect(rgb)
        assert [d.label for d in dt] == [d.label for d in do]
        assert np.allclose([d.box for d in dt], [d.box for d in do], atol=0.05)
    with pytest.raises(DetectorError, match="v2i_config"):
        import onnx
        model = onnx.load(onnx_path)
        del model.metadata_props[:]
        make_detector("onnx", weights=model.SerializeToString())


def test_flip_and_scale_jitter_keep_boxes_on_the_vehicle(data):
    """Under random flips, scales and placements the transformed box still frames the drawn vehicle:
    its pixels differ from the empty scene, the pixels just outside it mostly do not."""
    from rsu_app.perception.synthetic import background

    ds = load_dataset(data)
    s = next(s for s in ds.samples if len(s.truths) == 1)
    img, bg = s.load(), background(640, 480, 3)
    cfg = ModelConfig(width=8, input_size=(192, 144))
    rng = np.random.default_rng(0)
    flips = 0
    for _ in range(12):
        state = rng.bit_generator.state
        out, M = _geometry(rng, img, cfg, 0.3, True)
        rng.bit_generator.state = state
        out_bg, M_bg = _geometry(rng, bg, cfg, 0.3, True)
        assert np.array_equal(M, M_bg)
        flips += M[0, 0] < 0
        u0, v0, u1, v1 = s.truths[0].box
        p = M @ np.array([[u0, u1], [v0, v1], [1, 1]])
        a0, a1 = sorted(p[0])
        b0, b1 = sorted(p[1])
        x0, x1, y0, y1 = int(round(a0)), int(round(a1)), int(round(b0)), int(round(b1))
        if x0 < 2 or y0 < 2 or x1 > 190 or y1 > 142:
            continue  # cropped: nothing to compare outside
        diff = np.abs(out.astype(int) - out_bg.astype(int)).max(axis=2) > 30
        inside = diff[y0 + 1:y1 - 1, x0 + 1:x1 - 1].mean()
        ring = np.concatenate([diff[y0 - 2, x0:x1], diff[y1 + 1, x0:x1], diff[y0:y1, x0 - 2], diff[y0:y1, x1 + 1]])
        assert inside > 0.6 and ring.mean() < 0.2, (inside, ring.mean(), M)
    assert flips > 0


def test_crop_targets_follow_the_window_and_crop_training_learns(data):
    """A training crop's heat peaks sit where the vehicles' boxes land in the window; training on
    crops lowers the loss; a crop that is not a multiple of 16 or exceeds the input is refused."""
    from rsu_app.perception.train import sample_item

    ds = load_dataset(data)
    cfg = ModelConfig(width=8, input_size=(192, 144))
    rng = np.random.default_rng(4)
    peaks = 0
    for i, s in enumerate(ds.samples):
        state = rng.bit_generator.state
        x, heat, weight, ind, size, offset, mask = sample_item(ds, i, cfg, rng, False, crop=(96, 64))
        assert x.shape == (3, 64, 96) and heat.shape == (2, 16, 24)
        rng.bit_generator.state = state
        full = sample_item(ds, i, cfg, rng, False)  # same window draw: the full image, un-cropped
        # the crop is a window of the full input: find it and compare pixels
        X = full[0]
        hits = [(y0, x0) for y0 in range(0, 144 - 64 + 1) for x0 in range(0, 192 - 96 + 1)
                if np.array_equal(X[:, y0:y0 + 64, x0:x0 + 96], x)]
        assert hits
        y0, x0 = hits[0]
        for k in np.flatnonzero(mask):
            cy, cx = divmod(int(ind[k]), 24)
            assert heat[:, cy, cx].max() == 1.0
            fy, fx = cy + y0 // 4, cx + x0 // 4  # the same vehicle's peak in the full image's heat
            assert full[1][:, max(0, fy - 1):fy + 2, max(0, fx - 1):fx + 2].max() > 0.5
            peaks += 1
    assert peaks >= 3
    # full-convolution heads: this checks cropping, not the head kind, and the width-8 separable heads
    # need more than 20 epochs of small windows (the default heads learn in test_learns_the_toy_set...)
    hist = train(data, None, epochs=20, seed=0, augment=False, lr=4e-3, crop=(96, 96), heads="conv",
                 **TINY)["training"]["history"]
    assert np.mean([h["loss"] for h in hist[-3:]]) < 0.5 * hist[0]["loss"], hist
    with pytest.raises(ValueError, match="crop"):
        train(data, None, epochs=1, crop=(100, 96), **TINY)
    with pytest.raises(ValueError, match="crop"):
        train(data, None, epochs=1, crop=(208, 96), **TINY)


def test_bad_dataset_and_config(tmp_path, data):
    with pytest.raises(DatasetError, match="no annotations.json"):
        train(tmp_path, None, epochs=1, **TINY)
    doc = json.loads((data / "annotations.json").read_text())
    doc["annotations"][0]["bbox"] = [0, 0, math.nan, 5]
    bad = tmp_path / "bad"
    (bad / "images").mkdir(parents=True)
    (bad / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match=r"annotations\[0\]"):
        load_dataset(bad)
    with pytest.raises(ValueError, match="multiples of 16"):
        ModelConfig(input_size=(320, 250))
    with pytest.raises(DetectorError, match="checkpoint"):
        (tmp_path / "x.pt").write_bytes(b"not a checkpoint")
        make_detector("torch", weights=tmp_path / "x.pt")


def test_cli_train_eval_export(data, tmp_path, capsys):
    from master.cli import main

    w = tmp_path / "cli.pt"
    assert main(["train-detector", "--data", str(data), "--out", str(w), "--epochs", "1", "--threads", "1",
                 "--width", "8"]) == 0
    assert "wrote" in capsys.readouterr().out
    assert torch.load(w, weights_only=True)["training"]["command"].startswith("v2i train-detector")
    assert main(["eval-detector", "--data", str(data), "--weights", str(w), "--json", "--threads", "1"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["images"] == 12 and set(rep["ap50"]) == {"car", "emergency", "overall"}
    assert rep["ap50_interval"] == {} and rep["bootstrap"] == 0
    assert main(["eval-detector", "--data", str(data), "--weights", str(w), "--json", "--bootstrap", "200"]) == 0
    ci = json.loads(capsys.readouterr().out)["ap50_interval"]
    assert set(ci) >= {"car", "overall"} and all(0.0 <= lo <= hi <= 1.0 for lo, hi in ci.values())
    assert main(["eval-detector", "--data", str(data), "--weights", str(w), "--bootstrap", "-5"]) == 2
    assert "--bootstrap -5: the number of resamples must be >= 0" in capsys.readouterr().err
    # --ground needs what a rendered set has (tests/test_perception_evaluate.py scores the ground error)
    assert main(["eval-detector", "--data", str(data), "--weights", str(w), "--ground"]) == 2
    assert "has no camera or vehicle positions" in capsys.readouterr().err
    assert main(["eval-detector", "--data", str(data), "--weights", str(w), "--ground-score", "0.5"]) == 2
    assert "--ground-score 0.5: needs --ground" in capsys.readouterr().err
    assert main(["export-detector", "--weights", str(w), "--out", str(tmp_path / "m.onnx")]) == 0
    assert main(["eval-detector", "--data", str(data), "--detector", "onnx", "--weights",
                 str(tmp_path / "m.onnx")]) == 0
    assert "AP50" in capsys.readouterr().out
    assert main(["eval-detector", "--data", str(data), "--detector", "yolo", "--weights", str(w)]) == 2
    assert "known: classical, onnx, torch" in capsys.readouterr().err
    assert main(["eval-detector", "--data", str(data), "--detector", "onnx", "--compile"]) == 2
    assert "detector 'onnx' does not take option 'compile'" in capsys.readouterr().err
    assert main(["eval-detector", "--data", str(tmp_path / "none")]) == 2


def test_cli_input_size_and_head_kind(data, tmp_path, capsys):
    """--input and --heads reach the checkpoint's config and the detector built from it; a bad size or
    head kind is refused naming the flag."""
    from master.cli import main

    w = tmp_path / "in.pt"
    assert main(["train-detector", "--data", str(data), "--out", str(w), "--epochs", "1", "--threads", "1",
                 "--width", "8", "--input", "256x192", "--heads", "conv", "--crop", "128x96"]) == 0
    capsys.readouterr()
    cfg = torch.load(w, weights_only=True)["config"]
    assert cfg["input_size"] == [256, 192] and cfg["heads"] == "conv"
    det = make_detector("torch", weights=w, threads=1)
    assert det.cfg.input_size == (256, 192) and isinstance(det.net.heat[0][0], torch.nn.Conv2d)
    assert det.net.heat[0][0].groups == 1  # a full 3x3 convolution, not a depthwise one
    assert main(["train-detector", "--data", str(data), "--out", str(w), "--input", "256by192"]) == 2
    assert "--input 256by192: expected WxH" in capsys.readouterr().err
    assert main(["train-detector", "--data", str(data), "--out", str(w), "--input", "250x192"]) == 2
    assert "multiples of 16" in capsys.readouterr().err
    with pytest.raises(ValueError, match="heads must be one of"):
        ModelConfig(heads="wide")


def test_checkpoint_without_head_kind_loads_as_full_convolutions(tmp_path):
    """Checkpoints written before ModelConfig.heads existed (full 3x3 head convolutions) still load and
    give the same outputs as the network that wrote them."""
    from rsu_app.perception.model import FORMAT, CenterNet
    from rsu_app.perception.torch_backend import load_weights

    torch.manual_seed(0)
    net = CenterNet(ModelConfig(width=8, input_size=(192, 144), heads="conv")).eval()
    config = net.cfg.to_dict()
    del config["heads"]
    path = tmp_path / "old.pt"
    torch.save({"format": FORMAT, "config": config, "state_dict": net.state_dict()}, path)
    loaded, _ = load_weights(path)
    assert make_detector("torch", weights=path, threads=1).cfg.heads == "conv"
    x = torch.rand(1, 3, 144, 192)
    with torch.inference_mode():
        for a, b in zip(net(x), loaded(x)):
            assert torch.equal(a, b)


def test_fine_tuning_starts_from_the_checkpoint_and_keeps_its_shape(data, learnt, tmp_path):
    out, ckpt = learnt
    # the arguments for shape are overridden by the checkpoint's; a nearly frozen lr keeps its loss
    tuned = train(data, None, epochs=1, seed=0, augment=False, lr=1e-7, init=out,
                  **{**TINY, "width": 16, "input_size": (320, 240)})
    assert tuned["config"]["width"] == 8 and tuned["config"]["input_size"] == [192, 144]
    assert tuned["training"]["history"][0]["loss"] < 2 * ckpt["training"]["history"][-1]["loss"]
    fresh = train(data, None, epochs=1, seed=0, augment=False, lr=1e-7, **TINY)
    assert tuned["training"]["history"][0]["loss"] < 0.3 * fresh["training"]["history"][0]["loss"]
    init = tuned["training"]["init"]
    assert init["dataset_sha256"] == ckpt["training"]["dataset_sha256"] and len(init["state_sha256"]) == 64
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DetectorError, match="checkpoint"):
        train(data, None, epochs=1, init=tmp_path / "bad.pt", **TINY)


def test_heavily_occluded_vehicles_are_masked_out_of_the_loss(data, tmp_path):
    from dataclasses import replace

    from rsu_app.perception.train import sample_item

    ds = load_dataset(data)
    idx = next(i for i, s in enumerate(ds.samples) if s.truths)
    s = ds.samples[idx]
    cfg = ModelConfig(width=8, input_size=(192, 144))
    hidden = replace(s.truths[0], occlusion=0.8)
    ds.samples[idx] = replace(s, truths=[hidden, *s.truths[1:]])
    rng = lambda: np.random.default_rng(0)  # noqa: E731
    cls = cfg.classes.index(hidden.label)

    def peak_and_weight(max_occlusion):
        x, heat, weight, *_ = sample_item(ds, idx, cfg, rng(), augment=False, max_occlusion=max_occlusion)
        u0, v0, u1, v1 = (c * 192 / s.width / cfg.stride if k % 2 == 0 else c * 144 / s.height / cfg.stride
                          for k, c in enumerate(hidden.box))
        cy, cx = int((v0 + v1) / 2), int((u0 + u1) / 2)
        return heat[cls, cy, cx], weight[cls, cy, cx]

    assert peak_and_weight(None) == (1.0, 1.0)          # taught as a vehicle
    assert peak_and_weight(0.9) == (1.0, 1.0)           # 0.8 is below this limit
    assert peak_and_weight(0.75) == (0.0, 0.0)          # neither vehicle nor background
    doc = json.loads((data / "annotations.json").read_text())
    for a in doc["annotations"]:
        a.pop("occlusion", None)
    (tmp_path / "images").symlink_to(data / "images")
    (tmp_path / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="no-occlusion"):  # a set rendered without occlusion labels
        train(tmp_path, None, epochs=1, max_occlusion=0.75, **TINY)
    with pytest.raises(ValueError, match="max_occlusion"):
        train(data, None, epochs=1, max_occlusion=1.5, **TINY)


def test_class_weights_scale_each_class_s_terms_of_the_loss(data, tmp_path, capsys):
    """emergency=2 doubles exactly the emergency vehicles' part of the loss (their heatmap, hits and false
    alarms, and their box terms) and nothing of the cars'; weights of 1 are the plain loss; the CLI takes
    --class-weight CLASS=W and refuses a bad one naming it."""
    from master.cli import main
    from rsu_app.perception.model import CenterNet
    from rsu_app.perception.train import focal_loss, loss_fn, sample_item

    ds = load_dataset(data)
    cfg = ModelConfig(width=8, input_size=(192, 144))
    items = [sample_item(ds, i, cfg, np.random.default_rng(i), augment=False) for i in range(len(ds))]
    batch = [torch.from_numpy(np.stack(col)) for col in zip(*items)]
    torch.manual_seed(0)
    with torch.no_grad():
        out = CenterNet(cfg)(batch[0])
    heat, weight, ind, size, offset, mask = batch[1:]
    ev = cfg.classes.index("emergency")
    ones = torch.ones(len(cfg.classes))
    twice = torch.tensor([2.0 if c == "emergency" else 1.0 for c in cfg.classes])
    plain, _ = loss_fn(out, batch[1:])
    same, _ = loss_fn(out, batch[1:], ones)
    assert torch.allclose(plain, same, rtol=1e-6)
    # heatmap: the emergency channel counts twice (its loss alone, over the same count of objects, added once)
    c = slice(ev, ev + 1)
    ev_part = focal_loss(out[0][:, c], heat[:, c], weight[:, c]) * heat[:, c].eq(1).sum() / heat.eq(1).sum()
    assert torch.allclose(focal_loss(out[0], heat, weight, twice), focal_loss(out[0], heat, weight) + ev_part,
                          rtol=1e-5)
    # box terms: the emergency vehicles' size and offset errors count twice
    is_ev = torch.stack([heat[n, ev].view(-1)[ind[n]].ge(1.0) for n in range(len(ind))]).float() * mask
    assert is_ev.sum() > 0 and (mask - is_ev).sum() > 0  # the toy set has both classes
    _, p = loss_fn(out, batch[1:])
    _, w = loss_fn(out, batch[1:], twice)
    _, e = loss_fn(out, (heat, weight, ind, size, offset, is_ev))
    n_all, n_ev = float(mask.sum()), float(is_ev.sum())
    assert w["size"] == pytest.approx(p["size"] + e["size"] * n_ev / n_all, rel=1e-5)
    assert w["offset"] == pytest.approx(p["offset"] + e["offset"] * n_ev / n_all, rel=1e-5)
    w_ckpt = train(data, None, epochs=1, seed=0, class_weights={"emergency": 2.0}, **TINY)
    assert w_ckpt["training"]["class_weights"] == {"emergency": 2.0}
    with pytest.raises(ValueError, match="'ambulance'.*classes: car, emergency"):
        train(data, None, epochs=1, class_weights={"ambulance": 2.0}, **TINY)
    with pytest.raises(ValueError, match="emergency=0"):
        train(data, None, epochs=1, class_weights={"emergency": 0}, **TINY)
    assert main(["train-detector", "--data", str(data), "--out", str(tmp_path / "w.pt"), "--epochs", "1",
                 "--class-weight", "emergency"]) == 2
    assert "--class-weight emergency: expected CLASS=WEIGHT" in capsys.readouterr().err


def test_painted_occluders_shrink_the_boxes_they_hide():
    """`_occlude` paints a block from one side of a vehicle down to the image bottom; the truths are visible
    boxes, so a box loses exactly the columns the block covers over its full height, and a box left with
    less than MIN_VISIBLE_SHARE of itself is masked out of the loss. Painted pixels are found by painting
    two images of different grounds with the same draws (the block is the same in both)."""
    from rsu_app.perception.train import MIN_VISIBLE_SHARE, _occlude

    # small: within the car's left strip, and under 4 px wide: it draws no occluder of its own
    car, small = (80.0, 40.0, 120.0, 60.0), (84.0, 45.0, 87.0, 50.0)
    shrunk = hidden = 0
    for seed in range(60):
        imgs, out = [], []
        for ground in (0, 255):
            img = np.full((100, 200, 3), ground, np.uint8)
            boxes, ignore = [car, small], [False, False]
            _occlude(np.random.default_rng(seed), img, boxes, ignore, 1.0)
            imgs.append(img)
            out.append((boxes, ignore))
        assert out[0] == out[1]
        (new_car, new_small), (car_ignored, _) = out[0]
        painted = (imgs[0] == imgs[1]).all(axis=2)
        assert painted.any()
        full = painted[40:60, 80:120].all(axis=0)  # car columns the block covers over the car's height
        kept = [80 + i for i in np.flatnonzero(~full)]
        assert not car_ignored and (new_car[0], new_car[2] - 1) == (kept[0], kept[-1]), (seed, new_car, kept)
        assert new_car[1:4:2] == car[1:4:2]
        shrunk += new_car != car
        if painted[45:50, 84:87].all():  # the small vehicle is entirely behind the block
            hidden += 1
            assert out[0][1][1] and (new_small[2] - new_small[0]) * (new_small[3] - new_small[1]) < \
                MIN_VISIBLE_SHARE * 15
        else:
            assert not out[0][1][1] or new_small != small
    assert shrunk > 20 and hidden > 5, (shrunk, hidden)


def test_occluders_are_recorded_and_checked(data, tmp_path):
    with pytest.raises(ValueError, match="occluders must be within 0..1, got 1.5"):
        train(data, None, epochs=1, occluders=1.5, **TINY)
    ckpt = train(data, None, epochs=1, seed=0, occluders=0.5, **TINY)
    assert ckpt["training"]["occluders"] == 0.5
    plain = train(data, None, epochs=1, seed=0, **TINY)
    assert plain["training"]["occluders"] == 0.0
    assert any(not torch.equal(ckpt["state_dict"][k], plain["state_dict"][k]) for k in plain["state_dict"])


def test_torch_detector_runs_the_network_with_batchnorm_folded_in(data, learnt):
    """The detector runs a copy of the network with every BatchNorm folded into its convolution (the
    speed-up is measured in benchmarks/perception.py): its outputs are the trained network's to float
    rounding, and its boxes on every toy image are the same. A network still in training mode is refused:
    fusing would bake in statistics that training goes on changing."""
    from rsu_app.perception.model import decode, fuse_for_inference, preprocess
    from rsu_app.perception.torch_backend import load_weights

    out, _ = learnt
    plain, _ = load_weights(out)
    det = make_detector("torch", weights=out, threads=1, score_threshold=0.1)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in det.net.modules())
    assert sum(isinstance(m, torch.nn.BatchNorm2d) for m in plain.modules()) > 10
    assert det.net.stem[0][0].weight.is_contiguous(memory_format=torch.channels_last)
    assert any(float(m.running_var.sub(1).abs().max()) > 0.01 for m in plain.modules()
               if isinstance(m, torch.nn.BatchNorm2d))  # trained statistics: the fold is not a no-op
    compared = 0
    for s in load_dataset(data).samples[:6]:
        x, scale = preprocess(s.load(), plain.cfg)
        with torch.inference_mode():
            a = [o.numpy() for o in plain(torch.from_numpy(x))]
            b = [o.numpy() for o in det.net(torch.from_numpy(x))]
        for p, q in zip(a, b):
            assert np.allclose(p, q, atol=1e-4), float(np.abs(p - q).max())  # a wrong fold: ~0.1
        want = decode(*a, scale, 4, plain.cfg.classes, 0.1)
        got = [(*d.box, d.label) for d in det.detect(s.load())]
        assert [w[4] for w in want] == [g[4] for g in got]
        assert np.allclose([w[:4] for w in want], [g[:4] for g in got], atol=0.01)  # pixels
        compared += len(want)
    assert compared >= 4
    with pytest.raises(ValueError, match="training mode"):
        fuse_for_inference(load_weights(out)[0].train())


def test_heat_sigma_narrows_the_target_peak_and_is_checked(data, tmp_path, capsys):
    """The heat target's spread is a share of the box's size on each axis: 0.2 box widths from the centre
    the default (1/6) leaves exp(-0.72) of the peak, 0.1 leaves exp(-2) (where the focal loss then counts
    a high score as a false peak). Bad values are refused by train and the CLI, naming the setting; the
    value is recorded in the checkpoint."""
    from master.cli import main
    from rsu_app.perception.train import HEAT_SIGMA, make_targets

    cfg = ModelConfig(width=8, input_size=(320, 240))
    box = np.array([[40.0, 100.0, 240.0, 140.0]])  # 200 x 40 px: 50 x 10 output cells, centre (35, 30)
    for sigma, want in ((HEAT_SIGMA, math.exp(-0.72)), (0.1, math.exp(-2.0))):
        heat = make_targets(box, np.array([1]), np.array([False]), cfg, heat_sigma=sigma)[0]
        assert heat[1, 30, 35] == 1.0 and heat[0].max() == 0.0
        assert heat[1, 30, 45] == pytest.approx(want, rel=1e-5)  # 10 cells = 0.2 widths to the right
        assert heat[1, 32, 35] == pytest.approx(math.exp(-0.5 * (2 / (10 * sigma)) ** 2), rel=1e-5)
    for bad in (0.0, -0.1, 0.6):
        with pytest.raises(ValueError, match=f"heat_sigma must be within 0 < s <= 0.5.*got {bad}"):
            train(data, None, epochs=1, heat_sigma=bad, **TINY)
    assert main(["train-detector", "--data", str(data), "--out", str(tmp_path / "x.pt"), "--heat-sigma", "0.7"]) == 2
    assert "heat_sigma must be within" in capsys.readouterr().err
    assert train(data, None, epochs=1, seed=0, heat_sigma=0.1, **TINY)["training"]["heat_sigma"] == 0.1


def test_context_branch_starts_as_a_no_op_on_a_trained_network_and_then_learns(data, learnt, tmp_path, capsys):
    """`--context` with `--init`: the stride-32 branch is added to a checkpoint without one and gives the
    same outputs until trained (its last convolution starts at zero); one epoch of fine-tuning moves it
    off zero; the config records it and loads back; a checkpoint of another shape is
    refused naming what does not fit."""
    from master.cli import main
    from rsu_app.perception.model import CenterNet
    from rsu_app.perception.torch_backend import load_weights

    out, _ = learnt
    plain, ckpt = load_weights(out)
    grown = CenterNet(ModelConfig.from_dict({**ckpt["config"], "context": True}))
    missing, unexpected = grown.load_state_dict(ckpt["state_dict"], strict=False)
    assert not unexpected and missing and all(k.startswith("ctx.") for k in missing)
    grown.eval()
    x = torch.rand(1, 3, 144, 192)
    with torch.inference_mode():
        for a, b in zip(plain(x), grown(x)):
            assert torch.equal(a, b)
    tuned = train(data, None, epochs=1, seed=0, lr=1e-3, init=out, context=True,
                  **{k: v for k, v in TINY.items() if k not in ("width", "input_size")})
    assert tuned["config"]["context"] is True and tuned["training"]["context"] is True
    assert float(tuned["state_dict"]["ctx.2.weight"].abs().max()) > 0
    net, _ = load_weights(tuned)
    assert net.cfg.context and isinstance(net.ctx[-1], torch.nn.Conv2d)
    # a checkpoint of another shape is refused naming what does not fit, not half-loaded
    other = {**ckpt, "state_dict": {k: v for k, v in ckpt["state_dict"].items() if not k.startswith("heat.")}}
    with pytest.raises(DetectorError, match="do not fit the network their config describes: [0-9]+ missing \\(heat"):
        train(data, None, epochs=1, init=other, **{k: v for k, v in TINY.items() if k not in ("width", "input_size")})
    for config, why in (({**ckpt["config"], "deep_width": 32}, "deep_width must be an integer >= 8 x width"),
                        ({**ckpt["config"], "deep_width": "wide"}, "invalid literal for int"),
                        ({k: v for k, v in ckpt["config"].items() if k != "width"}, "no 'width'"),
                        ("garbage", "")):
        with pytest.raises(DetectorError, match=f"weights: the checkpoint's config does not describe a network: {why}"):
            load_weights({**ckpt, "config": config})
    resized = {**ckpt, "config": {**ckpt["config"], "width": 16}}
    shape = r"describes: [0-9]+ of another shape \(stem.0.0.weight \(8, 3, 3, 3\) \(the network's: \(16, 3, 3, 3\)\)"
    with pytest.raises(DetectorError, match=shape):
        load_weights(resized)
    w = tmp_path / "ctx.pt"
    assert main(["train-detector", "--data", str(data), "--out", str(w), "--epochs", "1", "--threads", "1",
                 "--width", "8", "--input", "208x144", "--context", "--crop", "128x96"]) == 0
    capsys.readouterr()
    assert torch.load(w, weights_only=True)["config"]["context"] is True
    assert make_detector("onnx", weights=w, threads=1).cfg.context  # exports and runs in onnxruntime


def test_fine_tuning_at_another_input_size_only_when_asked(data, learnt, tmp_path, capsys):
    """With --init the checkpoint's input size is kept unless --input is given; then the same weights are
    trained at the new size, and the checkpoint records it."""
    from master.cli import main

    out, _ = learnt  # trained at 192x144
    kept, resized = tmp_path / "kept.pt", tmp_path / "resized.pt"
    common = ["train-detector", "--data", str(data), "--init", str(out), "--epochs", "1", "--threads", "1",
              "--lr", "1e-7"]
    assert main(common + ["--out", str(kept)]) == 0
    assert main(common + ["--out", str(resized), "--input", "256x192"]) == 0
    capsys.readouterr()
    assert torch.load(kept, weights_only=True)["config"]["input_size"] == [192, 144]
    ckpt = torch.load(resized, weights_only=True)
    assert ckpt["config"]["input_size"] == [256, 192] and ckpt["config"]["width"] == 8
    assert make_detector("torch", weights=resized, threads=1).cfg.input_size == (256, 192)


def test_widening_keeps_what_the_network_computes_and_then_trains(data, learnt, tmp_path, capsys):
    """`--deep-width` with `--init`: the checkpoint gets more channels at stride 16 and 32 (with a context
    branch added at the same time) and computes what it did: exactly without the copies' noise, to the
    noise with it; the copies then differ from the channels they copy (or they would train as one); the
    config records the width and loads back in both backends; narrowing is refused naming both widths."""
    from master.cli import main
    from rsu_app.perception.model import CenterNet, widen
    from rsu_app.perception.torch_backend import load_weights

    out, _ = learnt  # width 8: 64 channels at stride 16
    net, ckpt = load_weights(out)
    with_ctx = CenterNet(ModelConfig.from_dict({**ckpt["config"], "context": True}))
    with_ctx.load_state_dict(ckpt["state_dict"], strict=False)
    with_ctx.ctx[-1].weight.data.normal_(0, 0.05)  # a trained-looking branch, so the widening is checked through it
    with_ctx.eval()
    x = torch.rand(1, 3, 144, 192)
    with torch.inference_mode():
        before = with_ctx(x)
        exact = widen(with_ctx, 96, seed=1, noise=0.0).eval()
        noisy = widen(with_ctx, 96, seed=1).eval()
        assert exact.cfg.deep == 96 and exact.s16[2][3][0].weight.shape[:2] == (96, 96)
        for a, b, c in zip(before, exact(x), noisy(x)):
            assert torch.allclose(a, b, atol=1e-5)
            assert torch.allclose(a, c, atol=1e-2) and not torch.allclose(a, c, atol=1e-7)
    w = noisy.s16[0][3][0].weight[:, :, 0, 0]  # the stride-16 stage's first pointwise convolution (96, 32)
    assert not any(torch.allclose(w[i], w[j]) for i in range(96) for j in range(i))
    with pytest.raises(ValueError, match="deep_width 32 is narrower than the network's 64"):
        widen(net, 32)
    tuned = train(data, None, epochs=1, seed=0, lr=1e-3, init=out, deep_width=96,
                  **{k: v for k, v in TINY.items() if k not in ("width", "input_size")})
    assert tuned["config"]["deep_width"] == 96 and tuned["training"]["deep_width"] == 96
    assert load_weights(tuned)[0].cfg.deep == 96
    with pytest.raises(ValueError, match="deep_width 48: the checkpoint .* already has 64 channels at stride 16"):
        train(data, None, epochs=1, init=out, deep_width=48,
              **{k: v for k, v in TINY.items() if k not in ("width", "input_size")})
    wide = tmp_path / "deep.pt"
    assert main(["train-detector", "--data", str(data), "--init", str(out), "--out", str(wide), "--epochs", "1",
                 "--threads", "1", "--deep-width", "80"]) == 0
    capsys.readouterr()
    assert torch.load(wide, weights_only=True)["config"]["deep_width"] == 80
    assert make_detector("onnx", weights=wide, threads=1).cfg.deep == 80  # exports and runs in onnxruntime
    assert main(["train-detector", "--data", str(data), "--out", str(tmp_path / "x.pt"), "--epochs", "1",
                 "--width", "8", "--deep-width", "32"]) == 2
    assert "deep_width must be an integer >= 8 x width (64), got 32" in capsys.readouterr().err


def test_coordinate_channels_tell_cells_where_they_are_and_start_as_a_no_op(data, learnt, tmp_path, capsys):
    """`--coords`: each stride-16 cell gets its place in the picture (x, y in -1..1, left and top -1), so that
    a cell can learn how far the border is (a cut vehicle's box ends there). Added to a trained network it
    changes nothing until trained; with weights, a featureless picture gives different outputs in cells far
    from the border (without it, only the padding tells cells apart, so those are equal); one epoch moves it
    off zero; the config records it, it survives widening and exports to onnx with the same outputs."""
    from master.cli import main
    from rsu_app.perception.model import CenterNet, picture_grid, widen
    from rsu_app.perception.onnx_backend import export_onnx
    from rsu_app.perception.torch_backend import load_weights

    g = picture_grid(torch.zeros(1, 5, 3, 4))
    assert g.shape == (1, 2, 3, 4)
    assert torch.allclose(g[0, 0, 1], torch.tensor([-0.75, -0.25, 0.25, 0.75]))  # x: across, the same on every row
    assert torch.allclose(g[0, 1, :, 2], torch.tensor([-2 / 3, 0.0, 2 / 3]))       # y: down
    out, _ = learnt
    plain, ckpt = load_weights(out)
    placed = CenterNet(ModelConfig.from_dict({**ckpt["config"], "coords": True}))
    missing, unexpected = placed.load_state_dict(ckpt["state_dict"], strict=False)
    assert not unexpected and sorted(missing) == ["coords.bias", "coords.weight"]
    placed.eval()
    grey = torch.full((1, 3, 288, 384), 0.45)  # 24x18 cells at stride 16: the middle ones see no border
    with torch.inference_mode():
        for a, b in zip(plain(grey), placed(grey)):
            assert torch.equal(a, b)
        mid = (slice(None), slice(None), slice(30, 42), slice(40, 56))  # stride-4 cells far from every border
        flat = plain(grey)[1][mid]
        assert torch.allclose(flat, flat[..., :1, :1].expand_as(flat), atol=1e-6)
        placed.coords.weight.normal_(0, 0.5)
        size = placed(grey)[1][mid]
        assert (size[0, 0, 0, -1] - size[0, 0, 0, 0]).abs() > 1e-3  # the same grey, told apart by place alone
        assert torch.allclose(widen(placed, 80, seed=2, noise=0.0).eval()(grey)[1], placed(grey)[1], atol=1e-5)
    tuned = train(data, None, epochs=1, seed=0, lr=1e-3, init=out, coords=True,
                  **{k: v for k, v in TINY.items() if k not in ("width", "input_size")})
    assert tuned["config"]["coords"] is True and tuned["training"]["coords"] is True
    assert float(tuned["state_dict"]["coords.weight"].abs().max()) > 0
    net, _ = load_weights(tuned)
    assert net.cfg.coords and load_weights(ckpt)[0].cfg.coords is False  # older checkpoints: no coordinates
    w = tmp_path / "coords.pt"
    torch.save(tuned, w)
    t = make_detector("torch", weights=w, threads=1, score_threshold=0.1)
    o = make_detector("onnx", weights=export_onnx(w), threads=1, score_threshold=0.1)
    for s in load_dataset(data).samples[:2]:
        assert all(np.abs(x - y).max() < 1e-4 for x, y in zip(t.raw(s.load())[:3], o.raw(s.load())[:3]))
    cli = tmp_path / "cli.pt"
    assert main(["train-detector", "--data", str(data), "--init", str(out), "--out", str(cli), "--epochs", "1",
                 "--threads", "1", "--coords"]) == 0
    capsys.readouterr()
    assert torch.load(cli, weights_only=True)["config"]["coords"] is True


def test_cut_rule_visible_keeps_edge_slivers_the_dataset_labels(data, tmp_path, capsys):
    """`v2i dataset` labels a vehicle the frame's edge cuts as a vehicle down to `min_visible_pixels`; the
    first rounds' rule ("half") ignores one the training crop cuts to less than half. Under "visible" the
    cut vehicle stays an example unless its visible pixels, scaled by the share of its box left in the
    window, fall below the dataset's threshold (from its info, else 40)."""
    from dataclasses import replace

    from master.cli import main
    from rsu_app.perception.dataset import Truth
    from rsu_app.perception.train import sample_item

    ds = load_dataset(data)
    s = ds.samples[0]
    assert s.truths[0].visible_pixels is not None  # read from annotations.json
    cfg = ModelConfig(width=8, input_size=(192, 144))
    # a vehicle filling the frame: a 96x64 window keeps 96*64 / (192*144) = 2/9 of its box, and less
    # than half its height, whatever the window's place
    frame = (0.0, 0.0, float(s.width), float(s.height))

    def example(rule, visible, crop=(96, 64)):
        ds.samples[0] = replace(s, truths=[Truth(frame, "car", visible_pixels=visible)])
        _, heat, weight, _, _, _, mask = sample_item(ds, 0, cfg, np.random.default_rng(0), False, crop=crop,
                                                     cut_rule=rule)
        assert (mask.sum() == 1) == (weight.min() == 1.0)  # an example, or ignored: never both
        return int(mask.sum())

    assert example("half", 10000) == 0
    assert example("visible", 10000) == 1
    assert example("visible", 200) == 1       # 200 * 2/9 = 44 visible pixels left >= 40
    assert example("visible", 150) == 0       # 33 < 40
    assert example("visible", None) == 1      # without the count: the box's area, the frame's
    assert example("half", 150, crop=None) == example("visible", 150, crop=None) == 1  # not cut: the label decides
    ds.info = {**ds.info, "min_visible_pixels": 100}
    assert example("visible", 200) == 0       # the dataset's own threshold: 44 < 100
    with pytest.raises(ValueError, match="cut_rule 'visibel' is not one of half, visible .did you mean 'visible'"):
        train(data, None, epochs=1, cut_rule="visibel", **TINY)
    w = tmp_path / "v.pt"
    assert main(["train-detector", "--data", str(data), "--out", str(w), "--epochs", "1", "--threads", "1",
                 "--width", "8", "--crop", "96x64", "--cut-rule", "visible"]) == 0
    assert torch.load(w, weights_only=True)["training"]["cut_rule"] == "visible"
    assert train(data, None, epochs=1, **TINY)["training"]["cut_rule"] == "half"
    capsys.readouterr()
    # the CLI lists the rules without importing torch: its choices must stay train's
    import argparse

    from rsu_app.perception.cli import add_parser
    from rsu_app.perception.train import CUT_RULES
    sub = argparse.ArgumentParser().add_subparsers()
    add_parser(sub)
    action, = (a for a in sub.choices["train-detector"]._actions if "--cut-rule" in a.option_strings)
    assert tuple(action.choices) == CUT_RULES and action.default == "half"
    # bad counts in a dataset are named, not multiplied
    doc = json.loads((data / "annotations.json").read_text())
    (tmp_path / "images").symlink_to(data / "images")
    doc["annotations"][1]["visible_pixels"] = "many"
    (tmp_path / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match=r"annotations\[1\]: visible_pixels must be a number >= 0 .*'many'"):
        load_dataset(tmp_path)
    doc["annotations"][1]["visible_pixels"] = 120
    doc["info"] = {**doc.get("info", {}), "min_visible_pixels": "forty"}
    (tmp_path / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="needs info.min_visible_pixels .* got 'forty'"):
        train(tmp_path, None, epochs=1, cut_rule="visible", **TINY)
    assert train(tmp_path, None, epochs=1, **TINY)["training"]["cut_rule"] == "half"  # the old rule never reads it


def test_training_on_several_folders_joins_them_and_records_each(data, tmp_path, capsys):
    """The shipped detector learns from the same scenes drawn by two renderers: `--data` repeated joins the
    folders in order, and the checkpoint names each one's digest, so the exact data stays traceable."""
    import hashlib

    from master.cli import main

    other = write_dataset(tmp_path / "other", n_images=5, seed=11, max_vehicles=2)
    (other / "render.json").write_text(json.dumps({"renderer": "egl", "frames": {"egl": 5}}))  # as `v2i dataset`
    joined = train([data, other], None, epochs=1, seed=0, **TINY)["training"]
    one, two = load_dataset(data).digest(), load_dataset(other).digest()
    assert joined["images"] == 17
    assert [(d["sha256"], d["images"]) for d in joined["datasets"]] == [(one, 12), (two, 5)]
    assert [d["renderer"] for d in joined["datasets"]] == [None, "egl"]  # the toy set says nothing
    assert joined["dataset_sha256"] == hashlib.sha256(f"{one}+{two}".encode()).hexdigest()
    swapped = train([other, data], None, epochs=1, seed=0, **TINY)["training"]
    assert swapped["dataset_sha256"] != joined["dataset_sha256"]  # the order is part of what was trained on
    single = train([data], None, epochs=1, seed=0, **TINY)["training"]
    assert single["dataset_sha256"] == one and single["images"] == 12  # one folder: as before
    # categories must agree, and a bad folder is named among good ones
    doc = json.loads((other / "annotations.json").read_text())
    doc["categories"] = [{"id": c["id"], "name": {"car": "emergency", "emergency": "car"}[c["name"]]}
                         for c in doc["categories"]]
    (other / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match=f"{other}: categories .* differ"):
        train([data, other], None, epochs=1, **TINY)
    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    (empty / "annotations.json").write_text(json.dumps({"images": [], "annotations": [], "categories": []}))
    bare = write_dataset(tmp_path / "bare", n_images=3, seed=12)
    doc = json.loads((bare / "annotations.json").read_text())
    for a in doc["annotations"]:
        a.pop("occlusion")  # as `v2i dataset --no-occlusion` writes them
    (bare / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError) as exc:  # every unusable folder named at once, before any training
        train([data, empty, bare], None, epochs=1, max_occlusion=0.75, **TINY)
    text = str(exc.value)
    assert f"{empty}: the dataset has no images" in text and f"{bare}: max_occlusion needs occlusion labels" in text
    w = tmp_path / "two.pt"
    assert main(["train-detector", "--data", str(data), "--data", str(tmp_path / "gone"), "--data",
                 str(tmp_path / "gone2"), "--out", str(w), "--epochs", "1"]) == 2
    err = capsys.readouterr().err
    assert f"--data {tmp_path / 'gone'}: not a folder" in err and f"--data {tmp_path / 'gone2'}" in err
    assert not w.exists()


def test_a_joined_sets_digests_read_each_image_once(data, tmp_path, monkeypatch):
    """Training records the joined digest and each folder's: both come from one read of every image (a
    joined 8000-frame set is 400 MB), and the digest is still that of the bytes on disk when first asked."""
    from pathlib import Path

    other = write_dataset(tmp_path / "other", n_images=5, seed=11, max_vehicles=2)
    joined = join_datasets([load_dataset(data), load_dataset(other)])
    reads: list[str] = []
    real = Path.read_bytes

    def counting(self):
        reads.append(self.name)
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", counting)
    first = joined.digest()
    parts = joined.part_digests()
    assert joined.digest() == first and joined.part_digests() == parts
    images = [r for r in reads if r != "annotations.json"]
    assert len(images) == 17, reads  # each image once, not once per call
    monkeypatch.setattr(Path, "read_bytes", real)
    assert parts == [load_dataset(data).digest(), load_dataset(other).digest()]  # fresh objects, same bytes
