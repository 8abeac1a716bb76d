"""The timing sweep's table (scenarios/sweeps/ima_timing.toml): per point, what the cav did.

    python scenarios/sweeps/ima_timing_report.py runs/sweeps/ima_timing [--md out.md] [--json out.json]

`v2i sweep` collects each point's metrics.json (verdict, min gap, PET); the cav's peak deceleration and
minimum speed are in its timeseries, and what the AV app decided is in its plan log, so this reads every
finished point's run folder and prints one Markdown table: per point the verdict, min gap, PET, the cav's
peak deceleration (its measured acceleration, cav.a) and minimum speed, whether the cav ever stood
(< 0.5 m/s) with its footprint in the ev's lane while the ev was within 3 s of it, the AV app's first
commit-or-yield choice for the ev (`why`, and the deceleration a stop before the zone needed then), and
which points need the RSU (collide without it, not with it); then an outcome map (speed x offset).
Only the standard library: it runs wherever the sweep ran.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
from pathlib import Path

LANE = (-3.5, 0.0)  # the eastbound lane (the ev's), y from .. to, m: the case study's road is 7 m wide
CAV = {"length": 4.5, "width": 1.8, "rear_overhang": 0.95}


def corners_y(x: float, y: float, yaw: float) -> list[float]:
    """y of the cav's footprint corners (pose = rear axle)."""
    lo, hi = -CAV["rear_overhang"], CAV["length"] - CAV["rear_overhang"]
    hw = CAV["width"] / 2
    c, s = math.cos(yaw), math.sin(yaw)
    return [y + u * s + v * c for u in (lo, hi) for v in (-hw, hw)]


def point_row(run: Path) -> dict:
    """What one run folder says."""
    out: dict = {}
    metrics = json.loads((run / "metrics.json").read_text())
    out.update(collision=bool(metrics.get("collision")), min_gap_m=metrics.get("min_gap_m"),
               pet_s=metrics.get("pet_s"), collision_s=metrics.get("first_collision_s"))
    with (run / "timeseries.csv").open() as f:
        rows = list(csv.DictReader(f))
    a = [float(r["cav.a"]) for r in rows]
    v = [float(r["cav.v"]) for r in rows]
    out["peak_decel"] = -min(min(a), 0.0)
    out["min_speed"] = min(v)
    stood = False
    for r in rows:
        if float(r["cav.v"]) >= 0.5:
            continue
        ys = corners_y(float(r["cav.x"]), float(r["cav.y"]), float(r["cav.yaw"]))
        in_lane = max(ys) > LANE[0] and min(ys) < LANE[1] and float(r["cav.x"]) > -3.5
        ev_v = max(float(r["ev.v"]), 0.1)
        ev_time = (float(r["cav.x"]) - CAV["length"] - float(r["ev.x"])) / ev_v
        if in_lane and -1.0 < ev_time < 3.0:
            stood = True
            break
    out["stood_in_lane"] = stood
    plans = run / "plan-cav.jsonl"
    first = None
    if plans.exists():
        for line in plans.read_text().splitlines():
            rec = json.loads(line)
            if rec.get("choices"):
                first = rec
                break
    if first is not None:
        ch = first["choices"][0]
        out.update(first_choice=ch[2], first_choice_t=first["t"], first_need_decel=ch[3])
    return out


def read_sweep(folder: Path) -> list[dict]:
    """Every finished point of the sweep folder (points.jsonl: written as points finish, so a sweep still
    running, or a subset of it, can be read too); the axes from the run folder's name (ev=37mph+1.00_rsu=on-ID)."""
    log = folder / "points.jsonl"
    if not log.exists():
        raise SystemExit(f"{folder}: no points.jsonl (run `v2i sweep scenarios/sweeps/ima_timing.toml` first)")
    points = {}
    for line in log.read_text().splitlines():
        rec = json.loads(line)
        run = Path(rec["run_dir"])
        name = re.fullmatch(r"ev=(\d+mph)([+-]\d+\.\d+)_rsu=(on|off)-\w+", run.name)
        if rec.get("status") != "ok" or name is None or not (run / "metrics.json").exists():
            continue
        points[run.name] = {"speed": name[1], "offset": float(name[2]), "rsu": name[3], **point_row(run)}
    return list(points.values())


def fmt(v, nd=2) -> str:
    if v is None or v == "":
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def markdown(points: list[dict]) -> str:
    by = {(p["speed"], p["offset"], p["rsu"]): p for p in points}
    lines = ["| ev speed | offset (s) | RSU | verdict | min gap (m) | PET (s) | peak decel (m/s^2) | min speed (m/s) "
             "| stood in lane | first choice (stop decel) | needs RSU |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in sorted(points, key=lambda p: (p["speed"], p["offset"], p["rsu"] != "on")):
        other = by.get((p["speed"], p["offset"], "off" if p["rsu"] == "on" else "on"))
        needs = "-" if other is None else fmt(p["rsu"] == "on" and not p["collision"] and other["collision"]
                                              if p["rsu"] == "on" else (other and not other["collision"]
                                                                        and p["collision"]))
        verdict = f"collision {fmt(p['collision_s'])} s" if p["collision"] else "no collision"
        choice = "-" if "first_choice" not in p else f"{p['first_choice']} ({fmt(p['first_need_decel'])})"
        lines.append(f"| {p['speed']} | {p['offset']:+.2f} | {p['rsu']} | {verdict} | {fmt(p['min_gap_m'])} "
                     f"| {fmt(p['pet_s'])} | {fmt(p['peak_decel'])} | {fmt(p['min_speed'])} "
                     f"| {fmt(p['stood_in_lane'])} | {choice} | {needs} |")
    offsets = sorted({p["offset"] for p in points})
    lines += ["", "Outcome map (C: collision, .: none; with the RSU / without it):", "",
              "| ev speed | " + " | ".join(f"{o:+.2f}" for o in offsets) + " |",
              "|---|" + "---|" * len(offsets)]
    for speed in sorted({p["speed"] for p in points}):
        cells = []
        for o in offsets:
            on, off = by.get((speed, o, "on")), by.get((speed, o, "off"))
            mark = lambda q: " " if q is None else ("C" if q["collision"] else ".")  # noqa: E731
            cells.append(f"{mark(on)}/{mark(off)}")
        lines.append(f"| {speed} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--md", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    points = read_sweep(args.folder)
    text = markdown(points)
    print(text)
    if args.md:
        args.md.write_text(text)
    if args.json:
        args.json.write_text(json.dumps(points, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
