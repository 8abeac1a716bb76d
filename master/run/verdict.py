"""The one-glance verdict of a run, printed at the end of `v2i run` and at the top of its report.

Kept apart from the report (matplotlib, PyAV) so the console summary stays light.
"""
from __future__ import annotations

from typing import Any

MISS_FRACTION = 0.01  # a realtime run that misses more deadlines than this did not keep real time


def verdict_lines(metrics: dict[str, Any]) -> list[str]:
    """The one-glance verdict (also printed at the end of `v2i run`)."""
    if not metrics:
        return []
    out = []
    if "collision" in metrics:
        if metrics["collision"]:
            fc = metrics.get("first_collision") or {}
            pair = " and ".join(fc.get("pair", []))
            out.append(f"collision: true — {pair} touch at t = {metrics['first_collision_s']:.2f} s"
                       + (f", {fc['relative_speed_mps']:.1f} m/s relative" if fc.get("relative_speed_mps") else ""))
        else:
            out.append("collision: false")
        gap, ttc, pet = metrics.get("min_gap_m"), metrics.get("min_ttc_s"), metrics.get("pet_s")
        out.append("min gap " + (f"{gap:.2f} m" if gap is not None else "n/a")
                   + ", min TTC " + (f"{ttc:.2f} s" if ttc is not None else "n/a")
                   + ", PET " + (f"{pet:.2f} s" if pet is not None else "n/a"))
    out += preemption_lines(metrics.get("preemption"))
    e2e = metrics.get("latency_ms", {}).get("e2e", {})
    if e2e.get("n"):
        out.append(f"E2E latency p50 {e2e['p50']:.1f} ms, p99 {e2e['p99']:.1f} ms (n = {e2e['n']}; "
                   f"{metrics.get('time_mode', '?')}, {metrics.get('latency_policy', '?')} latency policy)")
        rtf = metrics.get("rtf")
        if rtf and rtf != 1.0:  # realtime stamps are on the run clock: simulated ms = wall ms x rtf
            out.append(f"  wall clock at RTF {rtf:g}: p50 {e2e['p50'] / rtf:.1f} ms, p99 {e2e['p99'] / rtf:.1f} ms")
        bounds = metrics.get("clock_bound_ms")
        if bounds:  # realtime: a stage stamped by an app and by the master is good to the app's offset bound
            out.append("  stages stamped by an app and the master are good to the app's clock-offset bound: "
                       + ", ".join(f"{app} ±{ms:.2f} ms" for app, ms in bounds.items())
                       + " (E2E is on the master's clock alone)")
    return out


def preemption_lines(p: dict[str, Any] | None) -> list[str]:
    """Signal preemption (metrics.json's `preemption`): granted or not, request to green, the ev, red entries."""
    if not p:
        return []

    def num(value, fmt):
        return "n/a" if value is None else format(value, fmt)

    out = [f"preemption: {'granted' if p.get('granted') else 'not granted' if p.get('requested') else 'not requested'}"
           + (f" — SRM to green {p['srm_to_green_ms']:.0f} ms" if p.get("srm_to_green_ms") is not None else "")
           + f"; ev {p.get('ev') or '?'} delay {num(p.get('ev_delay_s'), '.2f')} s, stopped "
           + f"{num(p.get('ev_stopped_s'), '.2f')} s; red violations {p.get('red_violations', 0)}"]
    stages = {k: v for k, v in (p.get("stages_ms") or {}).items() if k != "serial_request_bytes" and v is not None}
    if stages:
        out.append("  stages: " + ", ".join(f"{k} {v:.1f} ms" for k, v in stages.items()))
    return out


def realtime_warning(meta: dict[str, Any]) -> str | None:
    """A loud line when a realtime run could not keep real time (None when it did, or was not realtime)."""
    rt = meta.get("realtime")
    if meta.get("mode") != "realtime" or not rt:
        return None
    steps = meta.get("steps_done") or 0
    misses = rt.get("deadline_misses") or 0
    lag = (rt.get("lag_s") or {}).get("p99")
    step = meta.get("step_s") or 0.0
    problems = []
    if steps and misses > MISS_FRACTION * steps:
        problems.append(f"{misses} of {steps} steps missed their deadline")
    if lag is not None and step and lag > step:
        problems.append(f"lag p99 {lag * 1e3:.1f} ms > one step ({step * 1e3:.1f} ms)")
    if not problems:
        return None
    achieved = (meta.get("rtf") or {}).get("achieved")
    return ("the run did not keep real time: " + "; ".join(problems)
            + (f" (achieved RTF {achieved:.2f}, target {rt.get('target_rtf')})" if achieved else "")
            + ": timings measured in it are not real-time figures")
