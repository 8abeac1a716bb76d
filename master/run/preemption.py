"""metrics.json's `preemption` section: what signal preemption did in a run, from the run's own records.

Generic on purpose (the master never imports an app): it reads the "evsp"
trace records any app left in trace.jsonl (the requesting vehicle's
`obu` and `srm_sent`, the RSU's `srm`, `preempt_call`, `preempt_ack`, `status`), the
controller's `<instance>.state_<group>` columns and the vehicles' `<name>.x`,
`.y`, `.v` columns of timeseries.csv, and the intersection and signal heads of
scenario.resolved.toml.

* granted: an RSU reported the request `granted`;
* srm_to_green_ms: the first SRM on the air -> the requested signal group
  green at the controller (0 when it already was);
* stages_ms: srm_air (the SRM's send -> its arrival at the RSU), rsu
  (arrival -> the preemption call), serial_round_trip (call -> the
  controller's acknowledgement, tick-dated), serial_wire (the SetPreempt and
  its acknowledgement on the RS-232 line: bytes x 10 / baud), controller (the
  acknowledgement -> green: the controller's clearance), ssm (green -> the
  RSU's `granted`);
* ev_delay_s: the requesting vehicle's time to leave the junction box minus
  the time at its initial speed over the same path; ev_stopped_s: its time
  below 0.1 m/s;
* red_violations: vehicles that entered the junction box while the signal
  group of their approach showed stop-And-Remain (the head facing them);
* cross_delay_s: the largest delay of the other vehicles (None without any).
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

GREEN = {5.0, 6.0}      # J2735 MovementPhaseState: permissive / protected movement allowed
RED = {3.0}             # stop-And-Remain
STOPPED_MS = 0.1


def _series(rows: list[dict[str, str]], column: str) -> list[tuple[float, float]]:
    out = []
    for r in rows:
        try:
            out.append((float(r["time"]), float(r[column])))
        except (KeyError, TypeError, ValueError):
            continue
    return out


def _state_column(rows: list[dict[str, str]], group: int) -> str | None:
    if not rows:
        return None
    return next((c for c in rows[0] if c.endswith(f".state_{group}")), None)


def _state_at(states: list[tuple[float, float]], t: float) -> float | None:
    value = None
    for ts, v in states:
        if ts > t + 1e-9:
            break
        value = v
    return value


def _world(run_dir: Path) -> tuple[float | None, list[dict[str, Any]]]:
    try:
        sc = tomllib.loads((run_dir / "scenario.resolved.toml").read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return None, []
    world = sc.get("world") or {}
    width = (world.get("intersection") or {}).get("road_width")
    return (float(width) if width else None), list(world.get("signals") or [])


def _vehicles(rows: list[dict[str, str]]) -> list[str]:
    if not rows:
        return []
    return sorted(c[:-2] for c in rows[0] if c.endswith(".x") and f"{c[:-2]}.y" in rows[0])


def _track(rows, name):
    xs, ys = _series(rows, f"{name}.x"), _series(rows, f"{name}.y")
    return [(t, x, y) for (t, x), (_, y) in zip(xs, ys)]


def _entry(track, half: float) -> tuple[float, float, float] | None:
    """(t, heading rad of travel, index) when the vehicle first enters the box |x|, |y| <= half."""
    for i, (t, x, y) in enumerate(track):
        if abs(x) <= half and abs(y) <= half:
            if i == 0:
                return None  # starts inside: it did not enter
            j = max(0, i - 10)
            return t, math.atan2(y - track[j][2], x - track[j][1]), i
    return None


def _group_facing(signals, travel: float) -> int | None:
    """The signal group of the head whose lamps face the vehicle (yaw opposite to its travel)."""
    best = None
    for s in signals:
        try:
            yaw = math.radians(float(s["yaw"]))
            group = int(s["signal_group"])
        except (KeyError, TypeError, ValueError):
            continue
        err = abs(math.remainder(yaw - (travel + math.pi), math.tau))
        if err <= math.radians(45.0) and (best is None or err < best[0]):
            best = (err, group)
    return None if best is None else best[1]


def _delay(rows, name, half: float) -> float | None:
    track, speeds = _track(rows, name), _series(rows, f"{name}.v")
    if len(track) < 2 or not speeds or speeds[0][1] <= 0:
        return None
    inside, dist = False, 0.0
    for i in range(1, len(track)):
        t, x, y = track[i]
        dist += math.hypot(x - track[i - 1][1], y - track[i - 1][2])
        now_inside = abs(x) <= half and abs(y) <= half
        if inside and not now_inside:
            return round((t - track[0][0]) - dist / speeds[0][1], 3)
        inside = inside or now_inside
    return None


def preemption_metrics(run_dir: Path, traces: list[dict[str, Any]], rows: list[dict[str, str]]) -> dict | None:
    """The `preemption` section (None when no app left an "evsp" record)."""
    recs = [r for r in traces if r.get("record") == "evsp" and isinstance(r.get("t"), (int, float))]
    if not recs:
        return None
    width, signals = _world(Path(run_dir))
    half = width / 2 if width else None
    sent = [r for r in recs if r.get("kind") == "srm_sent"]
    first = next((r for r in sent if r.get("srm") == "request"), None)
    ev = first.get("vehicle") if first else next((r.get("vehicle") for r in recs if r.get("kind") == "obu"), None)
    group = first.get("signal_group") if first else None
    statuses = [r for r in recs if r.get("kind") == "status"]
    granted = next((r for r in statuses if r.get("status") == "granted"), None)
    out: dict[str, Any] = {"requested": first is not None, "granted": granted is not None, "signal_group": group,
                           "srm_to_green_ms": None, "stages_ms": {}, "srm_sent": len(sent),
                           "rejected": sorted({r.get("reason") for r in statuses if r.get("status") == "rejected"})}
    column = _state_column(rows, group) if group else None
    states = _series(rows, column) if column else []
    t_green = None
    if first is not None and states:
        t0 = first["t"]
        if _state_at(states, t0) in GREEN:
            t_green = t0
        else:
            t_green = next((ts for ts, v in states if ts >= t0 - 1e-9 and v in GREEN), None)
        if t_green is not None:
            out["srm_to_green_ms"] = round((t_green - t0) * 1000.0, 3)
    if first is not None:
        stages: dict[str, float | None] = {}
        srm_rx = next((r for r in recs if r.get("kind") == "srm" and r["t"] >= first["t"] - 1e-9), None)
        call = next((r for r in recs if r.get("kind") == "preempt_call" and r.get("on")), None)
        ack = next((r for r in recs if r.get("kind") == "preempt_ack" and r.get("on")), None)

        def ms(a, b):
            return None if a is None or b is None else round((b - a) * 1000.0, 3)

        stages["srm_air"] = ms(first["t"], srm_rx and srm_rx["t"])
        stages["rsu"] = ms(srm_rx and srm_rx["t"], call and call["t"])
        stages["serial_round_trip"] = ms(call and call["t"], ack and ack["t"])
        stages["serial_wire"] = None if not ack or ack.get("wire_s") is None else round(ack["wire_s"] * 1000.0, 3)
        stages["serial_request_bytes"] = ack.get("request_bytes") if ack else None
        stages["controller"] = ms(ack and ack["t"], t_green) if t_green is None or not ack or t_green >= ack["t"] \
            else 0.0
        stages["ssm"] = ms(t_green, granted and granted["t"])
        out["stages_ms"] = stages
    vehicles = _vehicles(rows)
    out["ev"] = ev
    out["ev_delay_s"] = _delay(rows, ev, half) if ev in vehicles and half else None
    speeds = _series(rows, f"{ev}.v") if ev in vehicles else []
    out["ev_stopped_s"] = round(sum(t1 - t0 for (t0, v), (t1, _) in zip(speeds, speeds[1:]) if abs(v) < STOPPED_MS),
                                3) if speeds else None
    violations = []
    if half:
        for name in vehicles:
            entry = _entry(_track(rows, name), half)
            if entry is None:
                continue
            g = _group_facing(signals, entry[1])
            col = _state_column(rows, g) if g else None
            if col and _state_at(_series(rows, col), entry[0]) in RED:
                violations.append(name)
    out["red_violations"] = len(violations)
    out["red_violators"] = violations
    others = [d for d in (_delay(rows, n, half) for n in vehicles if n != ev) if d is not None] if half else []
    out["cross_delay_s"] = max(others) if others else None
    return out
