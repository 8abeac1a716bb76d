"""Scenario events: at a simulated time, or when a condition over the run's signals first holds, do something
to the run — kill, stop or pause an app, degrade a V2X link, set an FMU variable, inject a frame on the air or
garbage on the CAN bus or a serial link. Users of a safety tool need to see what their application does when
things go wrong; every event executed is in `events.jsonl` with its time.

    [[events]]
    at = 5.5                        # simulated seconds; or
    # when = "distance(cav, ev) < 30"   # the first step after which it holds (master.scenario.conditions)
    action = "kill"                 # see ACTIONS; each action's own keys below
    participant = "rsu"

Actions and their keys:

* `kill` / `stop` — `participant`: a participant the master started (SIGKILL / SIGTERM). In lockstep
  a required participant that dies ends the run naming it; one with `required = false` is dropped and the
  run goes on.
* `pause` — `participant`, `wall_s`: SIGSTOP, then SIGCONT after `wall_s` wall-clock seconds (an app that
  hangs for a while: in lockstep simulated time cannot pass while it is stopped, so a pause longer than
  its `timeout_s` ends the run naming it, a shorter one only delays the run).
* `link` — `link = "rsu->cav"` (`*` for any station), `loss` (0..1), `delay_s` (extra), `duration_s`
  (default: to the end): the V2X air drops or delays that link's frames for the period.
* `set` — `target = "inst.var"`, `value`: an FMU input or parameter set before the step.
* `inject_v2x` — `station` (a `[v2x.stations]` name), and `hex` or `file` (bytes as a station transmits
  them: J2735 in the 1609.2 envelope, or anything), `count` (default 1): published as if that station sent it.
* `inject_can` — `count` random frames (`seed`), or `can_id` + `data` (hex): sent on the CAN bus beside the
  AV app's, to the gateway (which tallies bad frames by reason and never stops).
* `inject_serial` — `serial` (a `[serial.NAME]`), `hex` or `garbage` (a byte count, `seed`), `to` =
  "fmu" | "client": bytes into the link as if the line carried them.

The events are parsed and checked with the file (every problem named `events[i].key: reason`), and run by
`ScenarioEvents`, a hook that acts before the step of their time.
"""
from __future__ import annotations

import random
import signal
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from master.scenario.conditions import Condition, ConditionError, compile_condition, signals_of
from master.hooks import Hook, Outcome, RunContext
from master.scenario.tables import did_you_mean as _did_you_mean

_COMMON = ("at", "when", "action")
ACTIONS: dict[str, tuple[str, ...]] = {  # action -> its own keys (required ones are checked per action)
    "kill": ("participant",),
    "stop": ("participant",),
    "pause": ("participant", "wall_s"),
    "link": ("link", "loss", "delay_s", "duration_s"),
    "set": ("target", "value"),
    "inject_v2x": ("station", "hex", "file", "count"),
    "inject_can": ("count", "seed", "can_id", "data"),
    "inject_serial": ("serial", "hex", "garbage", "seed", "to"),
}
SIGNALS = {"kill": signal.SIGKILL, "stop": signal.SIGTERM}
MAX_INJECT = 10_000  # frames or bytes one event may inject (load from tests stays bounded)


@dataclass
class Event:
    index: int
    action: str
    at: float | None = None
    when: Condition | None = None
    args: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"action": self.action}
        if self.at is not None:
            out["at"] = self.at
        if self.when is not None:
            out["when"] = self.when.text
        out.update({k: v for k, v in self.args.items() if k != "payload"})
        return out


# -- reading the section ------------------------------------------------------------------------------
def read_section(value: Any, context) -> list[Event] | None:
    """The reader of `[[events]]` (master.scenario.sections)."""
    participants = (context.raw.get("participants") or {}) if isinstance(context.raw.get("participants"), dict) \
        else {}
    stations = ((context.raw.get("v2x") or {}).get("stations") or {}) if isinstance(context.raw.get("v2x"), dict) \
        else {}
    serials = context.raw.get("serial") if isinstance(context.raw.get("serial"), dict) else {}
    return parse_events(value, context.instances, participants, stations, serials, context.base_dir,
                        context.time.stop, context.problem, "can" in context.raw)


def parse_events(value: Any, instances: dict, participants: dict, stations: dict, serials: dict,
                 base_dir: Path, stop: float, problem: Callable[[str, str], None], has_can: bool) -> list[Event]:
    if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
        problem("events", "expected an array of tables ([[events]])")
        return []
    signals, positions = signals_of(instances)
    out = []
    for i, raw in enumerate(value):
        key = f"events[{i}]"
        bad = lambda k, why, key=key: problem(f"{key}.{k}", why)  # noqa: E731
        action = raw.get("action")
        if action not in ACTIONS:
            bad("action", f"expected one of {', '.join(ACTIONS)}, got {action!r}"
                + did_you_mean(str(action), ACTIONS))
            continue
        allowed = _COMMON + ACTIONS[action]
        for k in raw:
            if k not in allowed:
                bad(k, f"unknown key for action {action!r} (expected one of: {', '.join(allowed)})"
                    + did_you_mean(k, allowed))
        event = Event(i, action)
        if ("at" in raw) == ("when" in raw):
            bad("at", "give exactly one of `at` (simulated seconds) or `when` (a condition)")
        elif "at" in raw:
            at = raw["at"]
            if not _number(at) or not 0.0 <= at <= stop:
                bad("at", f"expected simulated seconds in 0..{stop:g} (the run's stop), got {at!r}")
            else:
                event.at = float(at)
        else:
            try:
                event.when = compile_condition(raw["when"], signals, positions)
            except ConditionError as exc:
                bad("when", str(exc))
        _ACTION_ARGS[action](raw, event.args, bad, instances=instances, participants=participants,
                             stations=stations, serials=serials, base_dir=base_dir, has_can=has_can)
        out.append(event)
    return out


def did_you_mean(name: Any, options) -> str:
    hint = _did_you_mean(name, options)
    return f"; {hint}" if hint else ""


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _participant(raw, args, bad, participants, **_) -> None:
    name = raw.get("participant")
    if name not in participants:
        bad("participant", f"no [participants.{name}] in the scenario" + did_you_mean(str(name), participants))
    elif not (participants[name] or {}).get("command"):
        bad("participant", f"participant {name!r} is not started by the master (no command): it cannot be "
                           "signalled from here")
    else:
        args["participant"] = name


def _duration(raw, args, bad, required: bool) -> None:
    if "duration_s" not in raw:
        if required:
            bad("duration_s", "required: simulated seconds > 0")
        return
    d = raw["duration_s"]
    if not _number(d) or d <= 0:
        bad("duration_s", f"expected simulated seconds > 0, got {d!r}")
    else:
        args["duration_s"] = float(d)


def _pause(raw, args, bad, **kw) -> None:
    _participant(raw, args, bad, **kw)
    w = raw.get("wall_s")
    if not _number(w) or not 0 < w <= 600:
        bad("wall_s", f"required: wall-clock seconds in (0, 600], got {w!r}")
    else:
        args["wall_s"] = float(w)


def _link(raw, args, bad, stations, **_) -> None:
    link = raw.get("link")
    ends = link.split("->") if isinstance(link, str) else []
    if len(ends) != 2 or not all(e.strip() for e in ends):
        bad("link", f"expected \"TX->RX\" between [v2x.stations] names (* for any), got {link!r}")
    else:
        for end in (e.strip() for e in ends):
            if end != "*" and end not in stations:
                bad("link", f"no station {end!r} in [v2x.stations]" + did_you_mean(end, stations))
        args["link"] = "->".join(e.strip() for e in ends)
    loss, delay = raw.get("loss", 0.0), raw.get("delay_s", 0.0)
    if not _number(loss) or not 0.0 <= loss <= 1.0:
        bad("loss", f"expected a probability 0..1, got {loss!r}")
    if not _number(delay) or delay < 0:
        bad("delay_s", f"expected extra seconds >= 0, got {delay!r}")
    if _number(loss) and _number(delay) and loss == 0 and delay == 0:
        bad("loss", "a link event needs loss > 0 or delay_s > 0")
    args.update(loss=float(loss) if _number(loss) else 0.0, delay_s=float(delay) if _number(delay) else 0.0)
    _duration(raw, args, bad, required=False)


def _set(raw, args, bad, instances, **_) -> None:
    target = raw.get("target")
    inst, _, var = target.partition(".") if isinstance(target, str) else ("", "", "")
    if inst not in instances:
        bad("target", f"expected \"instance.variable\", no instance {inst!r}" + did_you_mean(inst, instances))
    else:
        names = [v.name for v in instances[inst].model_description.modelVariables]
        if var not in names:
            bad("target", f"{inst!r} has no variable {var!r}" + did_you_mean(var, names))
        else:
            args["target"] = target
    if "value" not in raw or not isinstance(raw["value"], (int, float, bool, str)):
        bad("value", "required: a number, boolean or string")
    else:
        args["value"] = raw["value"]


def _payload(raw, args, bad, base_dir: Path) -> None:
    if ("hex" in raw) == ("file" in raw):
        bad("hex", "give exactly one of `hex` or `file`")
        return
    if "hex" in raw:
        try:
            args["payload"] = bytes.fromhex(str(raw["hex"]).replace(" ", ""))
            args["hex"] = raw["hex"]
        except ValueError:
            bad("hex", "not hexadecimal")
    else:
        path = base_dir / str(raw["file"])
        try:
            args["payload"] = path.read_bytes()
            args["file"] = str(raw["file"])
        except OSError as exc:
            bad("file", f"cannot read {path}: {exc.strerror or exc}")


def _count(raw, args, bad, default: int | None) -> None:
    n = raw.get("count", default)
    if n is None:
        return
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_INJECT:
        bad("count", f"expected an integer 1..{MAX_INJECT}, got {n!r}")
    else:
        args["count"] = n


def _inject_v2x(raw, args, bad, stations, base_dir, **_) -> None:
    station = raw.get("station")
    if station not in stations:
        bad("station", f"no station {station!r} in [v2x.stations]" + did_you_mean(str(station), stations))
    else:
        args["station"] = station
    _payload(raw, args, bad, base_dir)
    _count(raw, args, bad, 1)


def _inject_can(raw, args, bad, has_can, **_) -> None:
    if not has_can:
        bad("action", "inject_can needs the scenario's [can] table (the bus to inject on)")
    if "data" in raw or "can_id" in raw:
        cid, data = raw.get("can_id"), raw.get("data")
        if not isinstance(cid, int) or isinstance(cid, bool) or not 0 <= cid <= 0x1FFFFFFF:
            bad("can_id", f"expected an arbitration id 0..0x1FFFFFFF, got {cid!r}")
        try:
            payload = bytes.fromhex(str(data))
            if len(payload) > 8:
                bad("data", f"at most 8 bytes on classic CAN, got {len(payload)}")
            args.update(can_id=cid, data=str(data))
        except ValueError:
            bad("data", "not hexadecimal")
        _count(raw, args, bad, 1)
    else:
        _count(raw, args, bad, None)
        if "count" not in args and "count" not in raw:
            bad("count", "give `count` random frames, or `can_id` and `data`")
        args["seed"] = int(raw.get("seed", 0))


def _inject_serial(raw, args, bad, serials, **_) -> None:
    name = raw.get("serial")
    if name not in serials:
        bad("serial", f"no [serial.{name}] in the scenario" + did_you_mean(str(name), serials))
    else:
        args["serial"] = name
    to = raw.get("to", "fmu")
    if to not in ("fmu", "client"):
        bad("to", f"expected \"fmu\" or \"client\", got {to!r}")
    args["to"] = to
    if ("hex" in raw) == ("garbage" in raw):
        bad("hex", "give exactly one of `hex` or `garbage` (a byte count)")
    elif "hex" in raw:
        try:
            args["payload"] = bytes.fromhex(str(raw["hex"]))
            args["hex"] = raw["hex"]
        except ValueError:
            bad("hex", "not hexadecimal")
    else:
        n = raw["garbage"]
        if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= MAX_INJECT:
            bad("garbage", f"expected a byte count 1..{MAX_INJECT}, got {n!r}")
        else:
            args["payload"] = random.Random(int(raw.get("seed", 0))).randbytes(n)
            args["garbage"] = n


_ACTION_ARGS = {"kill": _participant, "stop": _participant, "pause": _pause, "link": _link, "set": _set,
                "inject_v2x": _inject_v2x, "inject_can": _inject_can, "inject_serial": _inject_serial}


# -- running them -------------------------------------------------------------------------------------
@dataclass
class Targets:
    """What events act on: the master's hooks and members (each None when the scenario has none)."""

    participants: Any = None  # master.links.participants.ParticipantsHook
    radio: Any = None  # master.links.radio_bridge.RadioBridge
    can: Any = None  # master.links.can_bridge.CanBridge
    serial: Any = None  # master.links.serial_bridge.SerialBridges


class ScenarioEvents(Hook):
    """Runs the scenario's events before the step of their time (a `when` event: before the step after the
    one at whose end its condition first held); each executed once, logged to events.jsonl."""

    name = "scenario_events"  # its metadata section ("events" is the event log's counts)

    def __init__(self, events: list[Event], targets: Targets):
        self.events, self.targets = events, targets
        self.pending = [e for e in events if e.at is not None]
        self.watching = [e for e in events if e.when is not None]
        self.due_now: list[Event] = []
        self.done: list[dict[str, Any]] = []
        self.undo: list[tuple[float, Callable[[], None], dict[str, Any]]] = []
        self.timers: list[tuple[threading.Timer, Any]] = []
        self.t_last = 0.0
        self._getters: dict[str, Callable[[], float]] = {}
        self.ctx: RunContext | None = None

    def open(self, ctx: RunContext) -> dict[str, Any]:
        self.ctx = ctx
        for e in self.watching:
            for sig in e.when.signals:
                if sig not in self._getters:
                    inst, var = sig.split(".", 1)
                    fmu = ctx.members[inst].fmu
                    get = fmu.accessor(fmu.access_key(var), [fmu.variables[var].valueReference], setter=False)
                    self._getters[sig] = lambda get=get: float(get()[0])
        return {"scheduled": [e.describe() for e in self.events]}

    def before_step(self, k: int, t: float) -> None:
        self.t_last = t
        for when, undo, record in [u for u in self.undo if u[0] <= t + 1e-9]:
            self.undo.remove((when, undo, record))
            undo()
            self._log(t, {**record, "phase": "end"})
        due = self.due_now + [e for e in self.pending if e.at <= t + 1e-9]
        self.due_now = []
        for e in due:
            if e in self.pending:
                self.pending.remove(e)
            self._run(e, t)

    def after_step(self, k: int, t_next: float) -> None:
        if not self.watching:
            return
        value = lambda name: self._getters[name]()  # noqa: E731
        for e in list(self.watching):
            if e.when.holds(t_next, value):
                self.watching.remove(e)
                self.due_now.append(e)

    def _run(self, e: Event, t: float) -> None:
        record = {"event": "scenario_event", "index": e.index, **e.describe()}
        try:
            result = getattr(self, "_do_" + e.action)(e, t)
        except Exception as exc:  # an event that cannot act is recorded, never fatal to the run
            self._log(t, {**record, "error": f"{type(exc).__name__}: {exc}"})
            return
        self._log(t, {**record, **(result or {})})

    def _log(self, t: float, record: dict[str, Any]) -> None:
        entry = {"t": t, **record}
        self.done.append(entry)
        self.ctx.events(entry)

    # -- actions ----------------------------------------------------------------------------------------
    def _proc(self, name: str):
        hook = self.targets.participants
        proc = hook.procs.get(name) if hook is not None else None
        if proc is None or proc.poll() is not None:
            raise RuntimeError(f"participant {name!r} is not running")
        return proc

    def _do_kill(self, e: Event, t: float) -> dict[str, Any]:
        proc = self._proc(e.args["participant"])
        proc.send_signal(SIGNALS[e.action])
        return {"pid": proc.pid}

    _do_stop = _do_kill

    def _do_pause(self, e: Event, t: float) -> dict[str, Any]:
        proc = self._proc(e.args["participant"])
        proc.send_signal(signal.SIGSTOP)
        timer = threading.Timer(e.args["wall_s"], self._resume, (proc, e))
        timer.daemon = True
        self.timers.append((timer, proc))
        timer.start()
        return {"pid": proc.pid}

    def _resume(self, proc, e: Event) -> None:
        _resume(proc)
        self._log(self.t_last, {"event": "scenario_event", "index": e.index, "action": "pause",
                                "participant": e.args["participant"], "phase": "end"})

    def _do_link(self, e: Event, t: float) -> dict[str, Any]:
        radio = self.targets.radio
        if radio is None or getattr(radio, "air", None) is None:
            raise RuntimeError("the scenario has no V2X air ([v2x])")
        tx, rx = e.args["link"].split("->")
        handle = radio.air.impair(tx, rx, e.args["loss"], e.args["delay_s"])
        if "duration_s" not in e.args:
            return {}
        until = t + e.args["duration_s"]
        record = {"event": "scenario_event", "index": e.index, "action": "link", "link": e.args["link"]}
        self.undo.append((until, lambda: radio.air.restore(handle), record))
        return {"until": until}

    def _do_set(self, e: Event, t: float) -> dict[str, Any]:
        inst, var = e.args["target"].split(".", 1)
        fmu = self.ctx.members[inst].fmu
        fmu.set_by_name({var: e.args["value"]})
        return {}

    def _do_inject_v2x(self, e: Event, t: float) -> dict[str, Any]:
        radio = self.targets.radio
        if radio is None:
            raise RuntimeError("the scenario has no V2X air ([v2x])")
        for _ in range(e.args["count"]):
            radio.inject(e.args["station"], e.args["payload"], t)
        return {"bytes": len(e.args["payload"])}

    def _do_inject_can(self, e: Event, t: float) -> dict[str, Any]:
        can = self.targets.can
        if not can:
            raise RuntimeError("the scenario has no CAN bridge ([can])")
        if "can_id" in e.args:
            frames = [(e.args["can_id"], bytes.fromhex(e.args["data"]))] * e.args["count"]
        else:
            rng = random.Random(e.args["seed"])
            frames = [(rng.randrange(0x800), rng.randbytes(rng.randrange(9))) for _ in range(e.args["count"])]
        sent = can.inject(frames)
        return {"frames": sent}

    def _do_inject_serial(self, e: Event, t: float) -> dict[str, Any]:
        serial = self.targets.serial
        bridge = next((b for b in serial.bridges if b.spec.name == e.args["serial"]), None) if serial else None
        if bridge is None:
            raise RuntimeError(f"no serial bridge {e.args['serial']!r}")
        n = bridge.inject(e.args["payload"], e.args["to"], t)
        return {"bytes": n}

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        for _, undo, _ in self.undo:  # a degraded link is restored
            undo()
        self.undo.clear()
        for timer, proc in self.timers:  # a paused app is never left stopped
            timer.cancel()
            _resume(proc)
        return {"executed": [d for d in self.done if d.get("phase") != "end"],
                "not_reached": [e.describe() for e in self.pending + self.watching]}


def _resume(proc) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)
