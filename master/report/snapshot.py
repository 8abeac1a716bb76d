"""`v2i snapshot`: what the world looks like at one simulated time, as pictures.

Runs the scenario's co-simulation up to time T (the FMUs stepped exactly as
in `v2i run`; the world's sensors are skipped on the way, only the poses and
signal states at T matter), then builds a fresh World at those poses and
writes into the output folder:

* `<camera>.png`: each camera's rendered frame at T;
* `top_down.png`: a map from above (roads, sidewalks, buildings, signal
  heads with their lit lamp, vehicles as oriented boxes with heading arrows,
  each camera with the ground footprint of its field of view, and one lidar
  scan at T coloured by what each ray hit, vehicle hits highlighted);
* `snapshot.json`: the poses, speeds, signal states and lidar hits drawn.

It lives beside the stepping loop, not in `master/world/`, because it drives
both: `master.run.cosim` imports the world, so a world module importing the loop
would close an import cycle (tests/test_boundaries.py).

Module-level imports stay light (the CLI imports this file to build its
parser); pybullet and matplotlib are imported when a snapshot is taken.
"""
from __future__ import annotations

import dataclasses
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

FOOTPRINT_RANGE = 80.0  # m: where a camera's ground footprint is cut off (rays above the horizon end here)
EDGE_SAMPLES = 24  # points per image edge for the footprint outline


class SnapshotError(ValueError):
    """Bad input for a snapshot (exit code 2)."""


def check(scenario, t: float, cameras: list[str] | None) -> float:
    """Validate the request; returns T snapped to the step grid (raises SnapshotError)."""
    if scenario.world is None:
        raise SnapshotError(f"{scenario.path}: no [world] table: nothing to take a snapshot of")
    names = [c.name for c in scenario.world.cameras]
    for c in cameras or []:
        if c not in names:
            raise SnapshotError(f"--camera: unknown camera {c!r} (cameras: {', '.join(names) or 'none'})")
    tm = scenario.time
    if not math.isfinite(t) or t < tm.start:
        raise SnapshotError(f"--t: must be >= time.start ({tm.start}), got {t}")
    n = round((t - tm.start) / tm.step)
    if abs(tm.start + n * tm.step - t) > 1e-6 * tm.step + 1e-12:
        raise SnapshotError(f"--t: {t} is not on the {tm.step} s step grid from time.start {tm.start}")
    return tm.start + n * tm.step


def run_to(scenario, t: float, run_dir: Path) -> dict[str, Any]:
    """Run the co-simulation from time.start to t (sensors off); returns metadata["world"]."""
    from master.run.cosim import CoSimulation
    from master.world.world import WorldParticipant

    sc = dataclasses.replace(scenario, time=dataclasses.replace(scenario.time, stop=t))
    cosim = CoSimulation(sc, run_dir=run_dir, quiet=True)
    cosim.world = WorldParticipant(sc.world, sc.time.start, sensors=False)
    result = cosim.run()
    if result.status != "completed":
        raise RuntimeError(f"the run to t = {t} s {result.status}: {result.error}")
    return result.metadata["world"]


def camera_footprint(camera, max_range: float = FOOTPRINT_RANGE) -> list[tuple[float, float]]:
    """Outline (x, y) on the ground of what `camera` sees: the image border mapped through
    `pixel_to_ground`; rays that miss the ground or land beyond `max_range` stop at that range."""
    import numpy as np

    W, H = camera.spec.width, camera.spec.height
    s = np.linspace(0.0, 1.0, EDGE_SAMPLES, endpoint=False)
    border = ([(W * a, H) for a in s] + [(W, H * (1 - a)) for a in s]  # bottom left->right, right up
              + [(W * (1 - a), 0.0) for a in s] + [(0.0, H * a) for a in s])  # top right->left, left down
    cx, cy = camera.position[:2]
    out = []
    for u, v in border:
        p = camera.pixel_to_ground(u, v)
        if p is not None and math.hypot(p[0] - cx, p[1] - cy) <= max_range:
            out.append((float(p[0]), float(p[1])))
            continue
        ray = camera.R_wc @ np.linalg.solve(camera.K, np.array([u, v, 1.0]))
        n = math.hypot(ray[0], ray[1])
        if n > 1e-9:
            out.append((cx + max_range * ray[0] / n, cy + max_range * ray[1] / n))
    return out


def _view_limits(world, layout) -> tuple[float, float, float, float]:
    """A box around the junction, the vehicles, cameras and signal heads (clipped to the map)."""
    ix = layout.intersection
    core = ix.road_width / 2 + ix.sidewalk_width + 12.0
    xs, ys = [-core, core], [-core, core]
    for name, (x, y, yaw, _) in world.scene.poses.items():
        for cx, cy, _ in world.scene.vehicle_box_corners(name):
            xs.append(cx)
            ys.append(cy)
        back = layout.vehicles[name].length + 8.0  # room for the label behind it
        xs.append(x - back * math.cos(yaw))
        ys.append(y - back * math.sin(yaw))
    for c in layout.cameras:
        xs.append(c.x)
        ys.append(c.y)
    for s in layout.signals:
        xs.append(s.x)
        ys.append(s.y)
    pad, L = 8.0, ix.arm_length
    return (max(min(xs) - pad, -L), min(max(xs) + pad, L), max(min(ys) - pad, -L), min(max(ys) + pad, L))


def _draw_ground(ax, layout) -> None:
    from matplotlib.patches import Rectangle

    from master.world import scene as sc

    ix = layout.intersection
    L, hw, sw = ix.arm_length, ix.road_width / 2, ix.sidewalk_width
    ax.set_facecolor(sc.GROUND_RGB)
    ax.add_patch(Rectangle((-L, -hw), 2 * L, 2 * hw, color=sc.ROAD_RGB, zorder=1))
    ax.add_patch(Rectangle((-hw, -L), 2 * hw, 2 * L, color=sc.ROAD_RGB, zorder=1))
    if sw > 0:
        for sx in (-1, 1):
            for sy in (-1, 1):
                x0 = hw if sx > 0 else -L
                y0 = hw if sy > 0 else -hw - sw
                ax.add_patch(Rectangle((x0, y0), L - hw, sw, color=sc.SIDEWALK_RGB, zorder=1))
                x1 = hw if sx > 0 else -hw - sw
                y1 = hw + sw if sy > 0 else -L
                ax.add_patch(Rectangle((x1, y1), sw, L - hw - sw, color=sc.SIDEWALK_RGB, zorder=1))
    mark = dict(color=sc.MARK_RGB, lw=0.8, zorder=2)
    for s in (-1, 1):
        ax.plot([s * hw, s * L], [0, 0], ls=(0, (4, 4)), **mark)
        ax.plot([0, 0], [s * hw, s * L], ls=(0, (4, 4)), **mark)
    stop = hw + 1.0
    ax.plot([0, hw], [-stop, -stop], **mark)
    ax.plot([-hw, 0], [stop, stop], **mark)
    ax.plot([-stop, -stop], [-hw, 0], **mark)
    ax.plot([stop, stop], [0, hw], **mark)


def _draw_buildings(ax, layout, view) -> None:
    from matplotlib.patches import Rectangle

    from master.world.scene import BUILDING_RGB

    for b in layout.buildings:
        (x0, y0, _), (x1, y1, _) = b.bounds
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, facecolor=BUILDING_RGB, edgecolor="0.3", lw=1.0,
                               zorder=3))
        vx0, vx1, vy0, vy1 = view  # label the part in view
        cx0, cx1, cy0, cy1 = max(x0, vx0), min(x1, vx1), max(y0, vy0), min(y1, vy1)
        if cx0 < cx1 and cy0 < cy1:
            ax.text((cx0 + cx1) / 2, (cy0 + cy1) / 2, f"{b.name}\n{b.height:g} m", ha="center", va="center",
                    fontsize=8, zorder=4, clip_on=True)


def _draw_signals(ax, world, layout) -> None:
    from master.world import signals

    for s in layout.signals:
        state = world.scene.signal_states[s.name]
        lit = signals.lit_lamps(state)
        rgb = signals.LIT_RGB[lit[0]] if lit else (0.2, 0.2, 0.2)
        yaw = math.radians(s.yaw)
        fx, fy = s.x + 1.2 * math.cos(yaw), s.y + 1.2 * math.sin(yaw)
        ax.plot([s.x, fx], [s.y, fy], color="k", lw=1.5, zorder=6)
        ax.scatter([fx], [fy], s=45, color=[rgb], edgecolors="k", linewidths=0.8, zorder=7)
        ax.annotate(f"{s.name} (sg {s.signal_group}: {signals.state_name(state)})", (s.x, s.y), fontsize=7,
                    xytext=(4, -10), textcoords="offset points", zorder=7, clip_on=True)


def _draw_vehicles(ax, world, layout) -> None:
    from matplotlib.patches import Polygon

    for name, (x, y, yaw, v) in world.scene.poses.items():
        spec = layout.vehicles[name]
        corners = [(cx, cy) for cx, cy, cz in world.scene.vehicle_box_corners(name) if cz == 0.0]
        outline = [corners[0], corners[1], corners[3], corners[2]]  # rear right, rear left, front left, front right
        ax.add_patch(Polygon(outline, closed=True, facecolor=spec.color, edgecolor="k", lw=1.0, zorder=8))
        d = spec.centre_offset
        cx, cy = x + d * math.cos(yaw), y + d * math.sin(yaw)
        arrow = max(spec.length, 4.0)
        ax.annotate("", (cx + arrow * math.cos(yaw), cy + arrow * math.sin(yaw)), (cx, cy),
                    arrowprops=dict(arrowstyle="-|>", color="k", lw=1.2), zorder=9)
        # the label sits behind the vehicle, clear of its front (where sensors see it first)
        back = spec.length / 2 + 0.8
        c, s = math.cos(yaw), math.sin(yaw)
        ax.annotate(f"{name}\n{v * 3.6:.0f} km/h", (cx - back * c, cy - back * s), fontsize=8, fontweight="bold",
                    ha="right" if c > 0.5 else "left" if c < -0.5 else "center",
                    va="top" if s > 0.5 else "bottom" if s < -0.5 else "center", zorder=9, clip_on=True,
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.75))


def _draw_cameras(ax, world) -> None:
    from matplotlib.patches import Polygon

    for name, cam in world.cameras.items():
        outline = camera_footprint(cam)
        if len(outline) >= 3:
            ax.add_patch(Polygon(outline, closed=True, facecolor=(1.0, 0.9, 0.2, 0.05),
                                 edgecolor=(0.75, 0.55, 0.0), lw=1.0, ls="--", zorder=5))
        x, y = cam.position[:2]
        ax.scatter([x], [y], marker="s", s=40, color=(0.95, 0.75, 0.0), edgecolors="k", zorder=10)
        ax.annotate(f"{name} (z {cam.position[2]:g} m)", (x, y), fontsize=8, xytext=(6, 4),
                    textcoords="offset points", zorder=10, clip_on=True)


_HIT_STYLE = {  # kind -> (colour, size)
    "building": ((0.85, 0.3, 0.0), 3.0),
    "signal": ((0.0, 0.0, 0.0), 5.0),
    "road": ((0.45, 0.85, 1.0), 0.8),
    "sidewalk": ((0.2, 0.6, 0.95), 0.8),
    "ground": ((0.1, 0.35, 0.75), 0.8),
}


def _draw_scan(ax, world, name: str, scan) -> dict[str, int]:
    """Scatter the scan's hits by what they hit; returns the rays per vehicle hit."""
    import numpy as np

    pts = scan.world_points()
    labels = world.scene.labels
    kinds = np.array([labels.get(int(b), ("other", ""))[0] for b in scan.body_ids])
    for kind, (rgb, size) in _HIT_STYLE.items():
        sel = kinds == kind
        if sel.any():
            ax.scatter(pts[sel, 0], pts[sel, 1], s=size, color=[rgb], lw=0, zorder=4.5,
                       label=f"lidar: {kind} ({int(sel.sum())})")
    hits = world.hits_by_vehicle(scan)
    for other, n in hits.items():
        sel = scan.body_ids == world.scene.vehicle_ids[other]
        ax.scatter(pts[sel, 0], pts[sel, 1], s=14, color="magenta", edgecolors="k", linewidths=0.3, zorder=11,
                   label=f"lidar: vehicle {other} ({n})")
    x, y, yaw = scan.pose
    d = world.layout.vehicles[name].centre_offset
    ax.scatter([x + d * math.cos(yaw)], [y + d * math.sin(yaw)], marker="x", s=40, color="magenta", zorder=12)
    return hits


def top_down(world, layout, t: float, scans: dict, path: Path, title: str) -> dict[str, dict[str, int]]:
    """Write the map from above to `path`; returns the lidar hits per vehicle drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x0, x1, y0, y1 = _view_limits(world, layout)
    aspect = (y1 - y0) / (x1 - x0)
    fig, ax = plt.subplots(figsize=(12, max(4.0, min(14.0, 9 * aspect)) + 0.6))
    try:
        _draw_ground(ax, layout)
        _draw_buildings(ax, layout, (x0, x1, y0, y1))
        hits = {name: _draw_scan(ax, world, name, scan) for name, scan in scans.items()}
        _draw_cameras(ax, world)
        _draw_signals(ax, world, layout)
        _draw_vehicles(ax, world, layout)
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal")
        ax.set_xlabel("x east (m)")
        ax.set_ylabel("y north (m)")
        ax.set_title(title)
        if scans:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, markerscale=2.5, frameon=False)
        fig.tight_layout()
        fig.savefig(path, dpi=120)
    finally:
        plt.close(fig)
    return hits


def snapshot(scenario, t: float, out: Path, cameras: list[str] | None = None,
             keep_run: bool = False) -> list[Path]:
    """Run to t and write the pictures into `out`; returns the paths written."""
    import numpy as np
    from PIL import Image

    from master.world.world import World

    t = check(scenario, t, cameras)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if keep_run:
        meta = run_to(scenario, t, out / "run")
    else:
        with tempfile.TemporaryDirectory(prefix="v2i-snapshot-") as tmp:
            meta = run_to(scenario, t, Path(tmp) / "run")
    layout = scenario.world
    written: list[Path] = []
    with World(layout) as world:
        for name, (x, y, yaw) in meta["poses"].items():
            world.pose_vehicle(name, x, y, yaw, meta.get("speeds", {}).get(name, 0.0))
        for name, sig in meta.get("signals", {}).items():
            world.set_signal(name, sig["state"])
        for name, cam in world.cameras.items():
            if cameras and name not in cameras:
                continue
            frame = cam.render(t)
            path = out / f"{name}.png"
            Image.fromarray(np.ascontiguousarray(frame.rgb)).save(path)
            written.append(path)
        scans = {name: world.scan(name, t) for name in world.lidars}
        path = out / "top_down.png"
        hits = top_down(world, layout, t, scans, path, f"{scenario.name} at t = {t:.2f} s")
        written.append(path)
        record = {"scenario": scenario.name, "t": t,
                  "poses": meta["poses"], "speeds": meta.get("speeds", {}),
                  "signals": {n: s["state"] for n, s in meta.get("signals", {}).items()},
                  "lidars": {n: {"rays": s.n_rays, "hits": int(len(s.body_ids)), "vehicles": hits[n]}
                             for n, s in scans.items()}}
    path = out / "snapshot.json"
    path.write_text(json.dumps(record, indent=2) + "\n")
    written.append(path)
    return written


# -- command line ----------------------------------------------------------------------------
def _cmd(args) -> int:
    from master.scenario.loader import load_scenario_or_report

    sc = load_scenario_or_report(args.file)
    if sc is None:
        return 2
    t = sc.time.stop if args.t is None else args.t
    out = Path(args.out) if args.out else Path("runs") / f"{sc.name}-snapshot-t{t:g}"
    try:
        paths = snapshot(sc, t, out, args.camera or None, keep_run=args.keep_run)
    except SnapshotError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except FileExistsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for p in paths:
        print(p)
    return 0


def add_parser(sub) -> None:
    """Register `v2i snapshot` on the CLI's subparsers."""
    s = sub.add_parser("snapshot", help="run a scenario to time T and write camera frames and a top-down map")
    s.add_argument("file", help="scenario file with a [world] table")
    s.add_argument("--t", type=float, help="simulated time of the snapshot, s (default: time.stop)")
    s.add_argument("--out", help="output folder (default: runs/<scenario>-snapshot-t<T>)")
    s.add_argument("--camera", action="append", help="only this camera (repeatable; default: every camera)")
    s.add_argument("--keep-run", action="store_true", help="keep the run folder of the co-simulation in OUT/run")
    s.set_defaults(func=_cmd)
