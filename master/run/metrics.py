"""metrics.json: what a run of the case study measured, from what the run recorded.

Field names are a contract (README, "metrics.json"); sweeps collect them into
tables. Everything here is a pure function of the run's records, so a run
folder can be re-measured after the fact (`v2i report` does):

* the collision check's results (master.run.collision): `collision`,
  `first_collision_s`, `min_gap_m`, `min_ttc_s`, `pet_s`;
* `latency_ms`: `stage1`, `stage2`, `air`, `stage3`, `e2e`, each
  `{p50, p99, max, n}` in milliseconds of simulated time, from the apps' trace
  records (`trace.jsonl`, stamps named in bridges.v2x) joined with the CAN
  gateway's `can-applied.csv` (a record's AV_Command counter -> the time the
  gateway applied it, or a newer command that superseded it = CAN_APPLIED;
  realtime runs use the row's `t_clock`, the apps' clock);
* `pdr`: per directed link "tx->rx", frames delivered / frames decided
  (delivered + dropped; frames still in flight at the end are not decided),
  with the counts; `ipg_ms`: per link, the gaps between consecutive deliveries
  at the receiver;
* `aoi_ms`: age of information of a subject vehicle at a receiver: at every
  sample time after the first delivery, now - the camera-frame time of the
  freshest information about the subject that had arrived; `{p50, p99, max, n}`
  (the air ties each frame to the vehicle it describes, see master.links.radio_bridge);
* `v2x_rejected`: per receiving station, the frames its app refused, by reason
  (the verifier's and decoder's tally keys, e.g. `untrusted-signer`,
  `outside-time-window`), from the summary the app prints at its end
  (`participant-NAME.log`, the last JSON line with an `obu` section);
* `time_mode`, `rtf`, `latency_policy`: under which rules the numbers were taken
  (`rtf`: a realtime run's target real-time factor, None in lockstep; its
  stamps are on the run clock, so wall-clock milliseconds = latency / rtf).
"""
from __future__ import annotations

import bisect
import csv
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable

from bridges.v2x import CAN_APPLIED, CAN_COMMAND, STAGES, stage_ms, stamp_ns, stamp_s
from master.stats import percentiles
from master.run.preemption import preemption_metrics

METRICS = "metrics.json"
TRACE = "trace.jsonl"
APPLY_WINDOW_S = 2.0  # a record's counter is matched to an application at most this long after the command


def summary(samples: Iterable[float]) -> dict[str, float | int | None]:
    """{p50, p99, max, n} of samples (None values when there are none)."""
    s = percentiles(list(samples), (50, 99))
    return {"p50": s["p50"], "p99": s["p99"], "max": s["max"], "n": s["n"]}


# -- latency ----------------------------------------------------------------------------------------------
COUNTER_MODULO = 256  # AV_Command's rolling counter (bridges/can/cav.dbc)


class Applications:
    """When the gateway applied which AV_Command, on the clock the apps stamp with, in time order.

    A record's command counts as applied at the first application, at or after it was sent, of that
    command *or a newer one* (its counter or one up to half the counter space ahead, modulo 256): the
    gateway applies the newest command due at a step and supersedes older ones (it does whenever two
    arrive within one step, as in realtime runs), and the newer command carries the plan forward.
    Matching only the record's own counter left a superseded command without an E2E figure.
    """

    def __init__(self, entries: Iterable[tuple[float, int]] = ()):
        self.entries = sorted(entries)
        self.times = [t for t, _ in self.entries]

    def __eq__(self, other) -> bool:
        return isinstance(other, Applications) and self.entries == other.entries

    def __repr__(self) -> str:
        return f"Applications({self.entries!r})"

    def first(self, counter: int, sent: float) -> float | None:
        """The time the command `counter` sent at `sent` took effect; None if not within APPLY_WINDOW_S."""
        i = bisect.bisect_left(self.times, sent - 1e-9)
        for t, applied in self.entries[i:]:
            if t - sent > APPLY_WINDOW_S:
                return None
            if (applied - counter) % COUNTER_MODULO < COUNTER_MODULO // 2:
                return t
        return None


def applied_times(rows: Iterable[dict[str, str]]) -> Applications:
    """can-applied.csv rows -> the gateway's applications of AV_Commands: (time, counter), in time order."""
    entries = []
    for row in rows:
        if row.get("event") != "command" or not row.get("counter"):
            continue
        # t_clock: when it was applied on the run clock the apps stamp with (realtime; = t in lockstep)
        entries.append((float(row.get("t_clock") or row["t"]), int(row["counter"])))
    return Applications(entries)


def with_can_applied(record: dict[str, Any], applied: Applications) -> dict[str, int]:
    """A trace record's stamps, with CAN_APPLIED added when its command (or a newer one) was applied
    (Applications.first)."""
    stamps = {k: int(v) for k, v in record.get("stamps", {}).items()}
    counter = record.get("can_counter")
    if counter is None or CAN_COMMAND not in stamps:
        return stamps
    t = applied.first(int(counter), stamp_s(stamps[CAN_COMMAND]))
    if t is not None:
        stamps[CAN_APPLIED] = stamp_ns(t)
    return stamps


def latency_metrics(records: Iterable[dict[str, Any]], applied: Applications) -> dict[str, Any]:
    """latency_ms.{stage1, stage2, air, stage3, e2e} over every record that has both ends of a stage."""
    per_stage: dict[str, list[float]] = {name: [] for name in STAGES}
    for record in records:
        stamps = with_can_applied(record, applied)
        for name in STAGES:
            value = stage_ms(stamps, name)
            if value is not None:
                per_stage[name].append(value)
    return {name: summary(values) for name, values in per_stage.items()}


# -- the air ----------------------------------------------------------------------------------------------
def link_metrics(events: Iterable[dict[str, Any]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(pdr, ipg_ms) per directed link "tx->rx" from the air's events."""
    counts: dict[str, dict[str, int]] = defaultdict(lambda: {"delivered": 0, "dropped": 0})
    arrivals: dict[str, list[float]] = defaultdict(list)
    for e in events:
        kind = e.get("event")
        if kind not in ("v2x_delivered", "v2x_dropped") or "to" not in e:
            continue
        link = f"{e['from']}->{e['to']}"
        if kind == "v2x_delivered":
            counts[link]["delivered"] += 1
            arrivals[link].append(float(e["t"]))
        else:
            counts[link]["dropped"] += 1
    pdr = {}
    for link, c in sorted(counts.items()):
        decided = c["delivered"] + c["dropped"]
        pdr[link] = {"pdr": c["delivered"] / decided if decided else None, **c}
    ipg = {}
    for link, times in sorted(arrivals.items()):
        times.sort()
        ipg[link] = summary((b - a) * 1e3 for a, b in zip(times, times[1:]))
    return pdr, ipg


def aoi_metrics(deliveries: Iterable[tuple[float, float]], t_end: float, dt: float) -> dict[str, Any]:
    """Age of information: deliveries are (arrival time, camera-frame time of the information), sampled
    every dt from the first arrival to t_end."""
    items = sorted(deliveries)
    if not items:
        return summary([])
    ages, freshest, i = [], -math.inf, 0
    n = int(math.floor((t_end - items[0][0]) / dt + 1e-9)) + 1
    for k in range(n):
        t = items[0][0] + k * dt
        while i < len(items) and items[i][0] <= t + 1e-12:
            freshest = max(freshest, items[i][1])
            i += 1
        ages.append((t - freshest) * 1e3)
    return summary(ages)


def subject_deliveries(events: Iterable[dict[str, Any]], receiver: str, subject: str) -> list[tuple[float, float]]:
    """(arrival, frame time) of the frames delivered to `receiver` that the air tied to vehicle `subject`
    (its `v2x_delivered` events carry `subject` and `frame_t` when it could: see master.links.radio_bridge)."""
    return [(float(e["t"]), float(e["frame_t"])) for e in events
            if e.get("event") == "v2x_delivered" and e.get("to") == receiver and e.get("subject") == subject
            and e.get("frame_t") is not None]


# -- run folders ------------------------------------------------------------------------------------------
def read_jsonl(path: Path) -> list[dict[str, Any]]:
    """The JSON objects of a .jsonl file; a torn last line (a killed run) is skipped, not fatal."""
    out = []
    if not path.exists():
        return out
    for line in path.read_text().splitlines():
        try:
            item = json.loads(line)
        except ValueError:
            continue
        if isinstance(item, dict):
            out.append(item)
    return out


def read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def write_metrics(run_dir: Path, metrics: dict[str, Any]) -> Path:
    path = Path(run_dir) / METRICS
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(metrics, indent=2, default=str) + "\n")
    tmp.replace(path)
    return path


# -- one run ----------------------------------------------------------------------------------------------
AOI_DT_S = 0.01


def run_metrics(run_dir: Path, meta: dict[str, Any]) -> dict[str, Any] | None:
    """metrics.json of a run folder from its records (None when the run has none of the pieces).

    The collision fields come from the collision check's section of metadata.json;
    latency from trace.jsonl joined with can-applied.csv; pdr, ipg and age of
    information from the air's events in events.jsonl.
    """
    run_dir = Path(run_dir)
    collision = meta.get("collision")
    traces = read_jsonl(run_dir / TRACE)
    events = read_jsonl(run_dir / "events.jsonl")
    if collision is None and not traces and not any(e.get("event", "").startswith("v2x_") for e in events):
        return None
    out: dict[str, Any] = {"scenario": meta.get("scenario"), "status": meta.get("status"),
                           "stop_reason": meta.get("stop_reason")}
    if collision is not None:
        out.update(collision)
    out["latency_ms"] = latency_metrics(traces, applied_times(read_csv(run_dir / "can-applied.csv")))
    out["pdr"], out["ipg_ms"] = link_metrics(events)
    out["aoi_ms"] = _aoi(events, meta.get("sim_time_reached_s") or 0.0)
    out["v2x_rejected"] = rejected_by_receiver(run_dir)
    out["time_mode"] = meta.get("mode")
    out["rtf"] = (meta.get("realtime") or {}).get("target_rtf") if meta.get("mode") == "realtime" else None
    out["latency_policy"] = _policy(run_dir)
    out["clock_bound_ms"] = clock_bounds(meta)
    if any(r.get("record") == "evsp" for r in traces):  # the time series is read only for a preemption run
        preemption = preemption_metrics(run_dir, traces, read_csv(run_dir / "timeseries.csv"))
        if preemption is not None:
            out["preemption"] = preemption
    return out


def clock_bounds(meta: dict[str, Any]) -> dict[str, float] | None:
    """Realtime: {app: how far its run clock may sit from the master's, simulated ms}, None in lockstep.

    An app stamps its work on the master's clock through an offset it estimated by ping/pong, which is off
    by at most half the round trip of the exchange it kept (bridges.timesync.clock). So a latency stage
    stamped by that app at one end and the master at the other (stage 1 and the air: the RSU app; stage 3:
    the AV app) is good to that bound, and a short one can read that far below zero."""
    if meta.get("mode") != "realtime":
        return None
    rtf = (meta.get("realtime") or {}).get("target_rtf") or 1.0
    members = (meta.get("participants") or {}).get("members") or {}
    return {name: m["clock_offset"]["rtt_ns"] / 2 / 1e6 * rtf for name, m in sorted(members.items())
            if (m.get("clock_offset") or {}).get("rtt_ns") is not None}


def rejected_by_receiver(run_dir: Path) -> dict[str, dict[str, int]]:
    """{station: {reason: frames}} of every receiving app that summarised its OBU in its participant log.

    The apps count what they refuse (av_app.obu: forged, untrusted, expired, replayed, unsecured,
    malformed...) and print the tally in the JSON summary line at their end; the master only reads it.
    A receiver that refused nothing is listed with {}: it was there and everything it heard passed.
    """
    out: dict[str, dict[str, int]] = {}
    for path in sorted(Path(run_dir).glob("participant-*.log")):
        summary = _last_summary(path)
        if summary is None:
            continue
        station = str(summary.get("station") or path.stem[len("participant-"):])
        rejected = summary["obu"].get("rejected") or {}
        out[station] = {str(k): int(v) for k, v in sorted(rejected.items())}
    return out


def _last_summary(path: Path) -> dict[str, Any] | None:
    """The last line of a participant's log that is a JSON object with an `obu` table (None without one)."""
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            item = json.loads(line)
        except ValueError:
            continue
        if isinstance(item, dict) and isinstance(item.get("obu"), dict):
            return item
    return None


def _aoi(events: list[dict[str, Any]], t_end: float) -> dict[str, Any]:
    """Age of information per "receiver<-subject" (when the air tied frames to a vehicle), sampled every
    AOI_DT_S from the subject's first delivery to its last."""
    out: dict[str, Any] = {}
    pairs = {(e["to"], e["subject"]) for e in events
             if e.get("event") == "v2x_delivered" and e.get("subject") and "to" in e}
    for receiver, subject in sorted(pairs):
        deliveries = subject_deliveries(events, receiver, subject)
        # while the subject is being reported: from its first to its last delivery (after that the RSU has
        # lost sight of it, and an ever-growing age would say nothing about the link)
        last = max((arrival for arrival, _ in deliveries), default=t_end)
        out[f"{receiver}<-{subject}"] = aoi_metrics(deliveries, last, AOI_DT_S)
    return out


def _policy(run_dir: Path) -> str | None:
    """The lockstep latency policy of the run's [bridge] table (scenario.resolved.toml); None without apps."""
    import tomllib

    path = run_dir / "scenario.resolved.toml"
    try:
        return tomllib.loads(path.read_text()).get("bridge", {}).get("latency")
    except (OSError, ValueError):
        return None
