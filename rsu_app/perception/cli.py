"""`v2i train-detector`, `v2i eval-detector` and `v2i export-detector`.

The master's CLI finds them through the `v2i.commands` entry points (pyproject.toml) and never
imports the app; this module imports nothing of the project outside the app, and
nothing heavy at module level (torch is imported when a command runs). The tracker's evaluation on
a scenario, which needs the simulator's world, is `v2i eval-tracker` in `evaluation/`.

Exit codes as the rest of `v2i`: 0 success, 1 failure while running, 2 bad input.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    t = sub.add_parser("train-detector", help="train the RSU's CenterNet vehicle detector on a dataset folder")
    t.add_argument("--data", required=True, action="append",
                   help="dataset folder written by `v2i dataset`; repeat it to train on several at once (e.g. the "
                        "same scenes drawn by each renderer)")
    t.add_argument("--out", required=True, help="weights file to write (.pt)")
    t.add_argument("--epochs", type=int, default=30)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--threads", type=int, default=2,
                   help="CPU threads for torch (default 2: training owns the machine while it runs)")
    t.add_argument("--batch-size", type=int, default=8)
    t.add_argument("--lr", type=float, default=2e-3)
    t.add_argument("--width", type=int, default=16, help="channels of the first stage (speed/accuracy)")
    t.add_argument("--input",
                   help="network input WxH (multiples of 16) frames are resized to (default 320x240; with --init "
                        "the checkpoint's unless given)")
    t.add_argument("--heads", default="separable", choices=("separable", "conv"),
                   help="output-head blocks: depthwise-separable (default) or full 3x3 convolutions")
    t.add_argument("--crop", help="train on random WxH windows (multiples of 16) of the network input, e.g. 192x144")
    t.add_argument("--onnx", help="also export the trained network to this .onnx file")
    t.add_argument("--init", help="start from this checkpoint's weights (fine-tune); its width and heads are kept, "
                                  "and its input size unless --input is given")
    t.add_argument("--max-occlusion", type=float,
                   help="mask vehicles more hidden than this (0..1, from the dataset's occlusion labels) out "
                        "of the loss")
    t.add_argument("--occluders", type=float, default=0.0, metavar="P",
                   help="paint an occluder over each vehicle with probability P (0..1; default 0) and shrink its "
                        "box to what is left: half-hidden vehicles are the detector's weak spot")
    t.add_argument("--heat-sigma", type=float, metavar="S",
                   help="the heat target's standard deviation as a share of a box's width and height (0 < S <= "
                        "0.5; default 1/6): narrower peaks leave fewer second peaks on long vehicles")
    t.add_argument("--context", action="store_true",
                   help="add a stride-32 context branch (a wider view for each output cell); with --init it is "
                        "added to the checkpoint's network as a no-op, then trained")
    t.add_argument("--coords", action="store_true",
                   help="give each stride-16 cell its place in the picture (x, y channels), so it can tell how far "
                        "the border is; with --init added as a no-op, then trained")
    t.add_argument("--cut-rule", default="half", choices=("half", "visible"),
                   help="which vehicles the augmentation cuts at the picture's edge are ignored: 'half' (default) "
                        "those cut to less than half; 'visible' only those left with fewer visible pixels than the "
                        "dataset labels (its rule for the frame's edge), so slivers at the edge are examples")
    t.add_argument("--deep-width", type=int, metavar="N",
                   help="channels at stride 16 and 32 (default 8 x --width); with --init a checkpoint with fewer "
                        "is widened first, computing what it did, then trained")
    t.add_argument("--class-weight", action="append", default=[], metavar="CLASS=W",
                   help="weigh this class's objects W times in the loss (repeatable), e.g. emergency=2")
    t.set_defaults(func=_cmd_train)

    e = sub.add_parser("eval-detector", help="AP, recall by distance/occlusion and FPS of a detector on a dataset")
    e.add_argument("--data", required=True, help="dataset folder written by `v2i dataset`")
    e.add_argument("--detector", default="torch", help="backend: torch, onnx or classical (default torch)")
    e.add_argument("--weights", help="weights (.pt for torch; .onnx or .pt for onnx); default the shipped ones")
    e.add_argument("--background", help="classical: empty-scene image (default DIR/background.png if present, "
                                         "else MOG2 over the frames)")
    e.add_argument("--threads", type=int, default=1,
                   help="CPU threads of the detector (default 1: more oversubscribes a machine whose other "
                        "cores are busy; benchmarks/perception.py measures 1 and 2)")
    e.add_argument("--compile", action="store_true",
                   help="torch: run the network through torch.compile (faster; compiling takes seconds first)")
    e.add_argument("--score-threshold", type=float, default=0.05,
                   help="lowest score kept (low for AP; recall bins use it too)")
    e.add_argument("--bootstrap", type=int, default=0, metavar="N",
                   help="also give AP50 a 95 %% interval from N resamples of the images (e.g. 1000; default 0: "
                        "off); with a few hundred vehicles of a class one vehicle moves its AP50 by about 0.003")
    e.add_argument("--ground", action="store_true",
                   help="also place each found vehicle on the ground from its box (geo.ground_fix, the RSU app's "
                        "default box noise) and report the error from its true centre per class and distance, "
                        "beside the true boxes', with the normalised error that checks the covariance")
    e.add_argument("--ground-score", type=float, default=None,
                   help="--ground counts boxes with at least this score (default the RSU app's threshold, 0.6)")
    e.add_argument("--json", action="store_true", help="print JSON instead of a table")
    e.set_defaults(func=_cmd_eval)

    x = sub.add_parser("export-detector", help="export trained detector weights to ONNX")
    x.add_argument("--weights", required=True)
    x.add_argument("--out", required=True)
    x.set_defaults(func=_cmd_export)


def _cmd_train(args) -> int:
    from rsu_app.perception.dataset import DatasetError
    from rsu_app.perception.train import train

    missing = [d for d in args.data if not Path(d).is_dir()]
    if missing:
        print("error: " + "; ".join(f"--data {d}: not a folder" for d in missing), file=sys.stderr)
        return 2
    try:
        input_size = _size_arg("--input", args.input or "320x240")
        crop = _size_arg("--crop", args.crop) if args.crop else None
        class_weights = _class_weights(args.class_weight)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    command = "v2i " + " ".join(sys.argv[1:]) if sys.argv and sys.argv[0].endswith("v2i") else None
    try:
        ckpt = train(args.data, args.out, epochs=args.epochs, seed=args.seed, threads=args.threads,
                     batch_size=args.batch_size, lr=args.lr, width=args.width, crop=crop,
                     input_size=input_size, heads=args.heads, init=args.init, max_occlusion=args.max_occlusion,
                     class_weights=class_weights, occluders=args.occluders,
                     **({} if args.heat_sigma is None else {"heat_sigma": args.heat_sigma}), context=args.context,
                     override_input=args.input is not None, deep_width=args.deep_width, coords=args.coords,
                     cut_rule=args.cut_rule,
                     command=command or f"v2i train-detector {' '.join('--data ' + d for d in args.data)} "
                                        f"--out {args.out} "
                                        f"--epochs {args.epochs} --seed {args.seed} --threads {args.threads}")
    except (DatasetError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.onnx:
        from rsu_app.perception.onnx_backend import export_onnx

        export_onnx(ckpt, args.onnx)
    tr = ckpt["training"]
    print(f"trained {tr['epochs']} epochs on {tr['images']} images in {tr['seconds']} s; "
          f"final loss {tr['history'][-1]['loss']:.4f}; wrote {args.out}")
    return 0


def _class_weights(items: list[str]) -> dict[str, float]:
    """['emergency=2', ...] -> {'emergency': 2.0}, or ValueError naming the flag and the bad item."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--class-weight {item}: expected CLASS=WEIGHT, e.g. emergency=2") from None
    return out


def _size_arg(flag: str, text: str) -> tuple[int, int]:
    """'WxH' -> (W, H), or ValueError naming the flag."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"{flag} {text}: expected WxH, e.g. 192x144") from None
    return w, h


def _cmd_eval(args) -> int:
    from rsu_app.perception.dataset import DatasetError, load_dataset
    from rsu_app.perception.detector import DetectorError, make_detector
    from rsu_app.perception.evaluate import evaluate

    try:
        ds = load_dataset(args.data)
        opts: dict = {}
        if args.detector == "classical":
            bg = args.background or (Path(args.data) / "background.png")
            if Path(bg).is_file():
                opts["background"] = bg
            elif args.background:
                raise DetectorError(f"--background {args.background}: not found")
        else:
            opts.update(weights=args.weights, score_threshold=args.score_threshold)
            opts["threads"] = args.threads
        if args.compile:
            opts["compile"] = True  # make_detector names a backend that does not compile
        det = make_detector(args.detector, **opts)
    except (DatasetError, DetectorError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.ground_score is not None and not (args.ground and 0.0 <= args.ground_score <= 1.0):
        print(f"error: --ground-score {args.ground_score}: needs --ground and a score within 0..1", file=sys.stderr)
        return 2
    if args.ground and not any(s.camera and any(t.position is not None for t in s.truths) for s in ds.samples):
        print(f"error: --ground: {args.data} has no camera or vehicle positions (a set rendered by "
              f"`v2i dataset` has both)", file=sys.stderr)
        return 2
    if args.bootstrap < 0:
        print(f"error: --bootstrap {args.bootstrap}: the number of resamples must be >= 0", file=sys.stderr)
        return 2
    detections: list = []
    report = evaluate(det, ds, detections=detections, bootstrap=args.bootstrap)
    out = report.to_dict()
    text = report.table()
    if args.ground:
        from rsu_app.perception.evaluate import GROUND_SCORE, evaluate_ground

        ground = evaluate_ground(ds, detections, det.name, GROUND_SCORE if args.ground_score is None
                                 else args.ground_score)
        out["ground"] = ground.to_dict()
        text += "\n" + ground.table()
    print(json.dumps(out, indent=2) if args.json else text)
    return 0


def _cmd_export(args) -> int:
    from rsu_app.perception.detector import DetectorError
    from rsu_app.perception.onnx_backend import export_onnx

    try:
        data = export_onnx(args.weights, args.out)
    except DetectorError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({len(data)} bytes)")
    return 0
