"""`v2i report RUN_DIR [RUN_DIR2]`: one self-contained HTML page per run (or two side by side).

The page is what the seed paper shows as screenshots, from the run folder
alone: the verdict and metrics, top-down trajectories with time marks and
the buildings, speed profiles, the distance between the vehicles' footprints
over time, latency histograms per stage, and the RSU camera's clip (H.264
MP4 through PyAV) with what the RSU app reported for each frame (detections,
track ids, the BSM sent for each) drawn on it. A run with signal preemption
(metrics.json's `preemption`) also gets its figures and a signal timeline:
each signal group's state over time, the first SRM and the ev's green marked,
under the vehicles' speeds. PNG plots and the clip are
embedded (base64), so the page can be mailed or archived as one file; the
clip is also written beside it (`camera.mp4`).

Inputs (all optional but the time series; a missing piece leaves its section
out with a note): `timeseries.csv`, `metadata.json`, `metrics.json`,
`scenario.resolved.toml` (world layout: roads, buildings, vehicle sizes),
`trace.jsonl` (the apps' trace records), `can-applied.csv`, and the camera
archive `camera/<camera>/` (frames.csv, JPEG frames, camera.json).
"""
from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bridges.v2x import STAGES, stage_ms
from master.run.collision import Body
from master.run.metrics import METRICS, TRACE, Applications, applied_times, read_csv, read_jsonl, with_can_applied
from master.run.run_records import CAMERA_DIR
from master.run.verdict import verdict_lines

REPORT = "report.html"
CLIP = "camera.mp4"
DETECTIONS = "detections"  # kind of the RSU app's per-frame trace records drawn on the clip
_COLOURS = ["#1f5fbf", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf"]


class ReportError(ValueError):
    """A folder that is not a run folder (or lacks its time series); the message says which file."""


@dataclass
class Run:
    path: Path
    meta: dict[str, Any]
    metrics: dict[str, Any]
    scenario: dict[str, Any]
    series: dict[str, np.ndarray]
    traces: list[dict[str, Any]] = field(default_factory=list)
    applied: Applications = field(default_factory=Applications)

    @property
    def name(self) -> str:
        return self.meta.get("scenario") or self.path.name

    @property
    def world(self) -> dict[str, Any]:
        return self.scenario.get("world", {})

    def vehicles(self) -> list[str]:
        """Instances with x and y in the time series, in file order."""
        names = []
        for column in self.series:
            inst, _, var = column.partition(".")
            if var == "x" and f"{inst}.y" in self.series and inst not in names:
                names.append(inst)
        return names

    def pose(self, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x, y, yaw of a vehicle's rear axle over time (yaw from the path when not recorded)."""
        x, y = self.series[f"{name}.x"], self.series[f"{name}.y"]
        yaw = self.series.get(f"{name}.yaw")
        if yaw is None:
            yaw = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
            v0 = self.scenario.get("fmus", {}).get(name, {}).get("parameters", {}).get("yaw0")
            still = np.hypot(np.gradient(x), np.gradient(y)) < 1e-6
            if v0 is not None:
                yaw = np.where(still, float(v0), yaw)
        return x, y, yaw

    def body(self, name: str) -> Body | None:
        v = self.world.get("vehicles", {}).get(name)
        if not v:
            return None
        return Body(name, float(v["length"]), float(v["width"]), float(v["rear_overhang"]))


def load_run(path: str | Path) -> Run:
    path = Path(path)
    ts = path / "timeseries.csv"
    if not ts.is_file():
        raise ReportError(f"{path}: not a run folder (no timeseries.csv)")
    with open(ts, newline="") as f:
        rows = list(csv.reader(f))
    if len(rows) < 2:
        raise ReportError(f"{ts}: no rows")
    header, data = rows[0], rows[1:]
    series = {}
    for i, name in enumerate(header):
        try:
            series[name] = np.array([float(r[i]) for r in data])
        except (ValueError, IndexError):
            continue
    meta = _json(path / "metadata.json")
    metrics = _json(path / METRICS)
    resolved = path / "scenario.resolved.toml"
    scenario = tomllib.loads(resolved.read_text()) if resolved.is_file() else {}
    return Run(path, meta, metrics, scenario, series, read_jsonl(path / TRACE),
               applied_times(read_csv(path / "can-applied.csv")))


def _json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


# -- plots -----------------------------------------------------------------------------------------------
def _figure(width: float = 7.0, height: float = 4.5, **subplots):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=(width, height), dpi=100, **subplots)


def _png(fig) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def plot_top_down(run: Run, every_s: float = 1.0, zoom_m: float = 25.0) -> bytes:
    """The whole map with footprints every `every_s`, beside the junction (+-`zoom_m`) at twice that rate."""
    import matplotlib.pyplot as plt

    inter = run.world.get("intersection", {})
    half = float(inter.get("arm_length", 60.0))
    vehicles = run.vehicles()
    xs = np.concatenate([run.series[f"{v}.x"] for v in vehicles]) if vehicles else np.zeros(1)
    ys = np.concatenate([run.series[f"{v}.y"] for v in vehicles]) if vehicles else np.zeros(1)
    span = max(20.0, min(half, float(np.max(np.abs(np.concatenate([xs, ys])))) + 8.0))
    fig, (whole, junction) = plt.subplots(1, 2, figsize=(13, 6.5), dpi=100)
    _draw_top_down(whole, run, every_s, span, "{:.0f}")
    whole.set_title(f"{run.name}: top-down, footprints every {every_s:g} s (labels: t in s)", fontsize=10)
    _draw_top_down(junction, run, every_s / 2, min(zoom_m, span), "{:.1f}")
    junction.set_title(f"the junction, every {every_s / 2:g} s", fontsize=10)
    fig.tight_layout()
    return _png(fig)


def _draw_top_down(ax, run: Run, every_s: float, span: float, label: str) -> None:
    from matplotlib.patches import Polygon as Patch
    from matplotlib.patches import Rectangle

    inter = run.world.get("intersection", {})
    half, road = float(inter.get("arm_length", 60.0)), float(inter.get("road_width", 7.0))
    t = run.series["time"]
    ax.add_patch(Rectangle((-half, -road / 2), 2 * half, road, color="#d9d9d9", zorder=0))
    ax.add_patch(Rectangle((-road / 2, -half), road, 2 * half, color="#d9d9d9", zorder=0))
    ax.axhline(0, color="white", lw=1, ls="--", zorder=0)
    ax.axvline(0, color="white", lw=1, ls="--", zorder=0)
    for b in run.world.get("buildings", []):
        ax.add_patch(Rectangle((b["x"] - b["size_x"] / 2, b["y"] - b["size_y"] / 2), b["size_x"], b["size_y"],
                               color="#555555", zorder=1))
        ax.text(float(np.clip(b["x"], -span * 0.8, span * 0.8)), float(np.clip(b["y"], -span * 0.8, span * 0.8)),
                b.get("name", ""), color="white", ha="center", va="center", fontsize=8, clip_on=True)
    for cam in run.world.get("cameras", []):
        ax.plot(cam["x"], cam["y"], marker="^", color="black", ms=8, zorder=5)
        ax.annotate(cam["name"], (cam["x"], cam["y"]), textcoords="offset points", xytext=(4, 4), fontsize=8)
    step = max(1, int(round(every_s / (t[1] - t[0])))) if len(t) > 1 else 1
    for i, name in enumerate(run.vehicles()):
        colour = _COLOURS[i % len(_COLOURS)]
        x, y, yaw = run.pose(name)
        ax.plot(x, y, color=colour, lw=1.5, label=name, zorder=3)
        body = run.body(name)
        for k in range(0, len(t), step):
            if abs(x[k]) > span or abs(y[k]) > span:
                continue
            if body is not None:
                ax.add_patch(Patch(body.corners(x[k], y[k], yaw[k]), closed=True, fill=False, ec=colour, lw=0.8,
                                   zorder=4))
            ax.annotate(label.format(t[k]), (x[k], y[k]), fontsize=7, color=colour, zorder=6, annotation_clip=True)
    fc = run.metrics.get("first_collision")
    if fc:  # both bodies at first contact, filled, and a cross between them
        k = min(int(np.searchsorted(t, fc["t"] - 1e-9)), len(t) - 1)
        centres = []
        for name in fc["pair"]:
            body = run.body(name)
            if body is None or f"{name}.x" not in run.series:
                continue
            x, y, yaw = run.pose(name)
            corners = body.corners(x[k], y[k], yaw[k])
            ax.add_patch(Patch(corners, closed=True, fill=True, fc="#ff000055", ec="red", lw=1.2, zorder=6))
            centres.append(corners.mean(axis=0))
        if centres:
            cx, cy = np.mean(centres, axis=0)
            ax.plot(cx, cy, marker="X", color="red", ms=12, zorder=7)
            ax.annotate(f"contact {fc['t']:.2f} s", (cx, cy), textcoords="offset points", xytext=(8, -12),
                        color="red", fontsize=8, zorder=7)
    ax.set_xlim(-span, span)
    ax.set_ylim(-span, span)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.legend(loc="upper left", fontsize=8)


def plot_speeds(runs: list[Run]) -> bytes:
    fig, ax = _figure()
    for r, run in enumerate(runs):
        for i, name in enumerate(run.vehicles()):
            v = run.series.get(f"{name}.v")
            if v is None:
                continue
            ax.plot(run.series["time"], v * 3.6, color=_COLOURS[i % len(_COLOURS)],
                    ls=("-", "--")[r % 2], label=f"{name} ({run.name})" if len(runs) > 1 else name)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("speed (km/h)")
    ax.set_title("speed profiles")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


def gaps(run: Run) -> dict[str, np.ndarray]:
    """Distance between the footprints of each pair of vehicles over time (0: touching)."""
    import shapely

    names = [n for n in run.vehicles() if run.body(n) is not None]
    polys = {}
    for n in names:
        x, y, yaw = run.pose(n)
        body = run.body(n)
        polys[n] = shapely.polygons(np.stack([body.corners(a, b, c) for a, b, c in zip(x, y, yaw)]))
    out = {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            out[f"{a}-{b}"] = shapely.distance(polys[a], polys[b])
    return out


def plot_distance(runs: list[Run]) -> bytes:
    fig, ax = _figure()
    for r, run in enumerate(runs):
        for i, (pair, d) in enumerate(gaps(run).items()):
            ax.plot(run.series["time"], d, color=_COLOURS[(r * 3 + i) % len(_COLOURS)],
                    label=f"{pair} ({run.name})" if len(runs) > 1 else pair)
    ax.axhline(0, color="red", lw=0.8)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("gap between footprints (m)")
    ax.set_title("distance between the vehicles")
    ax.set_yscale("symlog", linthresh=1.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _png(fig)


_STATE_COLOURS = {1.0: "#444444", 3.0: "#d62728", 5.0: "#2ca02c", 6.0: "#2ca02c", 7.0: "#f0c000", 8.0: "#f0c000"}


def plot_signals(run: Run) -> bytes | None:
    """Each signal group's state (J2735 MovementPhaseState: dark, red, green, yellow) over time as a coloured
    band, the first SRM and the requested group's green marked; the vehicles' speeds below. None without
    signal states in the time series."""
    groups = sorted((c for c in run.series if c.rsplit(".", 1)[-1].startswith("state_")),
                    key=lambda c: int(c.rsplit("_", 1)[-1]) if c.rsplit("_", 1)[-1].isdigit() else 0)
    if not groups or "time" not in run.series:
        return None
    t = run.series["time"]
    fig, (ax, av) = _figure(7.0, 4.5 + 0.3 * len(groups), nrows=2, sharex=True,
                            gridspec_kw={"height_ratios": [1, 1.3]})
    for i, col in enumerate(groups):
        state = run.series[col]
        starts = np.flatnonzero(np.r_[True, state[1:] != state[:-1]])
        ends = np.r_[starts[1:], len(state) - 1]
        for a, b in zip(starts, ends):
            ax.broken_barh([(t[a], t[b] - t[a])], (i - 0.4, 0.8), color=_STATE_COLOURS.get(float(state[a]), "#bbbbbb"))
    ax.set_yticks(range(len(groups)), [f"group {c.rsplit('_', 1)[-1]}" for c in groups])
    pre = run.metrics.get("preemption") or {}
    first_srm = next((r.get("t") for r in run.traces if r.get("record") == "evsp" and r.get("kind") == "srm_sent"),
                     None)
    if first_srm is not None:
        for a in (ax, av):
            a.axvline(first_srm, color="k", ls="--", lw=1)
        ax.annotate("first SRM", (first_srm, len(groups) - 0.5), fontsize=8)
    if first_srm is not None and pre.get("srm_to_green_ms") is not None:
        green = first_srm + pre["srm_to_green_ms"] / 1000.0
        for a in (ax, av):
            a.axvline(green, color="#2ca02c", ls="--", lw=1)
        ax.annotate(f"group {pre.get('signal_group')} green", (green, -0.5), fontsize=8)
    ax.set_title("signal groups (red, yellow, green, dark)")
    for i, name in enumerate(run.vehicles()):
        if f"{name}.v" in run.series:
            av.plot(t, run.series[f"{name}.v"], color=_COLOURS[i % len(_COLOURS)], label=name)
    av.set_xlabel("time (s)")
    av.set_ylabel("speed (m/s)")
    av.legend(fontsize=8)
    return _png(fig)


def stage_samples(run: Run) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {name: [] for name in STAGES}
    for record in run.traces:
        stamps = with_can_applied(record, run.applied)
        for name in STAGES:
            value = stage_ms(stamps, name)
            if value is not None:
                out[name].append(value)
    return out


def plot_latency(run: Run) -> bytes | None:
    samples = {k: v for k, v in stage_samples(run).items() if v}
    if not samples:
        return None
    fig, axes = _figure(9, 2.2 * len(samples))
    fig.clf()
    axes = fig.subplots(len(samples), 1, squeeze=False)[:, 0]
    for ax, (stage, values) in zip(axes, samples.items()):
        ax.hist(values, bins=min(40, max(5, len(values) // 3)), color="#1f5fbf")
        ax.set_title(f"{stage}: p50 {np.median(values):.2f} ms, p99 {np.percentile(values, 99):.2f} ms, "
                     f"n = {len(values)}", fontsize=9)
        ax.set_xlabel("ms (simulated time)")
    return _png(fig)


# -- the clip ---------------------------------------------------------------------------------------------
def camera_frames(run: Run) -> tuple[str, list[tuple[int, float, Path]]] | None:
    """The first camera's archived frames: (camera name, [(frame id, t, jpeg path)])."""
    root = run.path / CAMERA_DIR
    if not root.is_dir():
        return None
    for cam in sorted(p for p in root.iterdir() if (p / "frames.csv").is_file()):
        rows = read_csv(cam / "frames.csv")
        frames = [(int(r["frame_id"]), float(r["t"]), cam / r["file"]) for r in rows if (cam / r["file"]).is_file()]
        if frames:
            return cam.name, frames
    return None


def make_clip(run: Run, out: Path, fps: float | None = None) -> dict[str, Any] | None:
    """Write the annotated camera clip (H.264 MP4); returns {frames, width, height, fps, camera} or None."""
    import av
    import cv2

    found = camera_frames(run)
    if found is None:
        return None
    camera, frames = found
    notes = {(r.get("camera"), int(r.get("frame_id", -1))): r for r in run.traces if r.get("kind") == DETECTIONS}
    if fps is None:
        ts = [t for _, t, _ in frames]
        fps = 1.0 / float(np.median(np.diff(ts))) if len(ts) > 1 else 10.0
    first = cv2.imread(str(frames[0][2]))
    height, width = first.shape[:2]
    verdict = verdict_lines(run.metrics)[:1]
    with av.open(str(out), mode="w") as container:
        stream = container.add_stream("libx264", rate=max(1, int(round(fps))))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "26", "preset": "veryfast"}
        for frame_id, t, path in frames:
            img = cv2.imread(str(path))
            _annotate(img, notes.get((camera, frame_id)), t, verdict)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return {"frames": len(frames), "width": width, "height": height, "fps": fps, "camera": camera}


def _annotate(img, note: dict[str, Any] | None, t: float, verdict: list[str]) -> None:
    import cv2

    if note:
        for obj in note.get("objects", []):
            u0, v0, u1, v1 = (int(round(c)) for c in obj["box"])
            colour = (40, 40, 230) if obj.get("label") == "emergency" else (230, 120, 30)
            cv2.rectangle(img, (u0, v0), (u1, v1), colour, 2)
            words = [obj.get("label", "?")]
            if obj.get("track") is not None:
                words.append(f"#{obj['track']}")
            if obj.get("bsm_id"):
                words.append(f"BSM {obj['bsm_id']}")
            cv2.putText(img, " ".join(words), (u0, max(12, v0 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1,
                        cv2.LINE_AA)
    cv2.putText(img, f"t = {t:5.2f} s", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
    for i, line in enumerate(verdict):
        cv2.putText(img, line[:70], (8, img.shape[0] - 10 - 18 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (255, 255, 255), 1, cv2.LINE_AA)


# -- the page ---------------------------------------------------------------------------------------------
def _img(data: bytes | None, alt: str) -> str:
    if data is None:
        return f"<p class='note'>{html.escape(alt)}: no data in this run.</p>"
    return f"<img alt='{html.escape(alt)}' src='data:image/png;base64,{base64.b64encode(data).decode()}'>"


def _metrics_table(m: dict[str, Any]) -> str:
    if not m:
        return "<p class='note'>no metrics.json in this run.</p>"
    rows = []
    for key in ("collision", "first_collision_s", "min_gap_m", "min_ttc_s", "pet_s", "time_mode", "latency_policy"):
        if key in m:
            rows.append((key, _fmt(m[key])))
    for stage, s in m.get("latency_ms", {}).items():
        rows.append((f"latency {stage} (ms)", f"p50 {_fmt(s.get('p50'))}, p99 {_fmt(s.get('p99'))}, "
                                             f"max {_fmt(s.get('max'))}, n {s.get('n')}"))
    for link, s in m.get("pdr", {}).items():
        rows.append((f"PDR {link}", f"{_fmt(s.get('pdr'))} ({s.get('delivered')} delivered, {s.get('dropped')} dropped)"))
    for subject, s in m.get("aoi_ms", {}).items():
        if isinstance(s, dict) and "p50" in s:
            rows.append((f"AoI {subject} (ms)", f"p50 {_fmt(s.get('p50'))}, p99 {_fmt(s.get('p99'))}"))
    pre = m.get("preemption") or {}
    for key in ("requested", "granted", "signal_group", "srm_to_green_ms", "ev", "ev_delay_s", "ev_stopped_s",
                "red_violations", "red_violators", "cross_delay_s"):
        if key in pre:
            rows.append((f"preemption {key}", _fmt(pre[key])))
    for stage, ms in (pre.get("stages_ms") or {}).items():
        rows.append((f"preemption stage {stage}", _fmt(ms)))
    return "<table>" + "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows) \
        + "</table>"


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.3f}" if math.isfinite(value) else str(value)
    return "n/a" if value is None else str(value)


def world_sensors_line(meta: dict[str, Any]) -> str | None:
    """Who drew the cameras and where the sensors ran, from metadata.json's world section (None without one)."""
    w = meta.get("world")
    if not isinstance(w, dict) or "renderer" not in w:
        return None
    where = ", ".join(w.get("sensor_processes") or []) or "none"
    out = [f"world: renderer {w['renderer']}; sensors in worker processes: {where}"]
    for kind in ("cameras", "lidars"):
        for name, s in (w.get(kind) or {}).items():
            p50 = (s.get("render_s") or s.get("scan_s") or {}).get("p50")
            out.append(f"{kind[:-1]} {name}: {s.get('frames', s.get('scans'))} taken"
                       + (f", p50 {p50 * 1e3:.0f} ms" if p50 is not None else "")
                       + (f", {s['dropped']} dropped" if s.get("dropped") else ""))
    return "; ".join(out)


def _column(run: Run, clip: dict[str, Any] | None, clip_bytes: bytes | None) -> str:
    status = run.meta.get("status", "?")
    parts = [f"<h2>{html.escape(run.name)}</h2>",
             f"<p class='path'>{html.escape(str(run.path))} — status {html.escape(str(status))}"
             + (f" ({html.escape(str(run.meta.get('stopped_by')))})" if run.meta.get("stopped_by") else "") + "</p>"]
    verdict = verdict_lines(run.metrics)
    if verdict:
        cls = "bad" if run.metrics.get("collision") else "good"
        parts.append(f"<div class='verdict {cls}'>" + "<br>".join(html.escape(v) for v in verdict) + "</div>")
    parts.append(_metrics_table(run.metrics))
    sensors = world_sensors_line(run.meta)
    if sensors:
        parts.append(f"<p class='note'>{html.escape(sensors)}</p>")
    parts.append(_img(plot_top_down(run), "top-down trajectories"))
    parts.append(_img(plot_latency(run), "latency per stage"))
    if run.metrics.get("preemption") is not None:
        parts.append(_img(plot_signals(run), "signal timeline"))
    if clip_bytes is not None:
        parts.append(f"<p>camera {html.escape(clip['camera'])}: {clip['frames']} frames, {clip['width']}x"
                     f"{clip['height']}, {clip['fps']:.0f} fps</p><video controls muted playsinline "
                     f"src='data:video/mp4;base64,{base64.b64encode(clip_bytes).decode()}'></video>")
    else:
        parts.append("<p class='note'>no camera archive in this run (no [world] camera).</p>")
    return "<div class='run'>" + "\n".join(parts) + "</div>"


_STYLE = """body{font-family:sans-serif;margin:1em;} .runs{display:flex;gap:2em;flex-wrap:wrap}
.run{flex:1;min-width:480px} img,video{max-width:100%} table{border-collapse:collapse;margin:0.5em 0}
th,td{border:1px solid #ccc;padding:2px 6px;text-align:left;font-size:90%} .note{color:#777}
.verdict{font-size:120%;padding:0.4em;margin:0.5em 0} .good{background:#dff0d8} .bad{background:#f2dede}
.path{color:#777;font-size:85%}"""


def write_report(run_dirs: list[str | Path], out: str | Path | None = None) -> tuple[Path, list[dict | None]]:
    """Write the page for one run (or two side by side); returns (page path, clip facts per run)."""
    runs = [load_run(p) for p in run_dirs]
    if out is None:
        out = runs[0].path / (REPORT if len(runs) == 1 else f"report-vs-{runs[1].path.name}.html")
    out = Path(out)
    columns, clips = [], []
    for run in runs:
        clip_path = run.path / CLIP
        clip = make_clip(run, clip_path) if camera_frames(run) is not None else None
        clips.append(clip)
        columns.append(_column(run, clip, clip_path.read_bytes() if clip else None))
    title = " vs ".join(r.name for r in runs)
    shared = _img(plot_speeds(runs), "speed profiles") + _img(plot_distance(runs), "distance between vehicles")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>"
            f"<div class='runs'>{''.join(columns)}</div><h2>Side by side</h2>{shared}</body></html>")
    out.write_text(page)
    return out, clips
