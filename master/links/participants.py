"""Participants: the apps (processes or boxes) that follow the master's clock over a bus.

Scenario file::

    [bridge]
    transport = "zenoh"           # "zenoh" (default), "udp" or "memory" (in-process, tests)
    prefix = "v2i/ima-1"          # default "v2i/<scenario name>-<random>": parallel runs stay apart
    listen = ["tcp/0.0.0.0:7447"] # zenoh: where the master listens (a box connects here)
    connect = []                  # zenoh: endpoints the master (and its child apps) connect to
    group = "239.255.77.1"        # udp: multicast group and port
    port = 47000
    options = {}                  # further transport options, passed through
    latency = "fixed"             # lockstep latency policy: "fixed" or "measured"
    join_timeout_s = 10.0         # wall seconds to wait for the required participants (and optional ones it started)
    heartbeat_s = 0.5             # participant and master heartbeat period
    heartbeat_timeout_s = 3.0     # silence after which a participant counts as lost
    on_refused = "wait"           # a refused join (wrong version...): "wait" for a good one, or "fail"

    [participants.rsu1]
    role = "rsu_app"              # checked against the role the app announces
    required = true               # false: the run goes on without it (dropped when lost)
    timeout_s = 5.0               # wall seconds to acknowledge a tick
    sync_every = 10               # tick at every 10th step
    latencies = { detect = 0.05, encode = 0.002 }   # fixed policy: simulated seconds per stage
    command = ["{python}", "-m", "rsu_app"]          # optional: started by the master ({python}: this
                                                     # Python, {name}: the participant, {run}: the run folder,
                                                     # {can.port}: any value of the scenario by its dotted key)
    args = ["--hardware", "cpu-i7"]                  # appended to command: what a variant or a sweep point
                                                     # changes (`v2i run ... --set participants.rsu1.args=[...]`)
    env = { RSU_CAMERA = "cam1" }
    enabled = true                # false: as if the table were not there (a scenario that extends
                                  # another one switches an app off this way)

A participant without `command` is one the user starts (or a box on the
network): the master waits `join_timeout_s` for it. A started one gets the
bus in its environment: V2I_BUS, V2I_PREFIX, V2I_CONNECT, V2I_BUS_OPTIONS,
V2I_NAME, V2I_ROLE, and the URL of each serial port of the run as
V2I_SERIAL_<NAME> (e.g. V2I_SERIAL_TLC=socket://127.0.0.1:40123); its output goes to `participant-<name>.log` in the run
folder. In lockstep the master ticks at each sync point before stepping and
waits for the acks; in realtime it publishes ticks and the sim/wall mapping and
never waits. The mapping (the run clock) is the pacer's schedule: it moves only
when the schedule does (the `slip` and `skip` overrun policies), and slews to a
schedule that moved back rather than stepping (bridges.timesync.clock.slewed:
signed messages are date-checked on it), so the apps'
stamps and the master's (RunContext.stamp_time) are on one clock; a loop that
cannot keep up falls behind the run clock and the run says so (deadline misses).
"""
from __future__ import annotations

import json
import logging
import os
import re
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from bridges.geo import GeoOrigin
from bridges.timesync import lifeline
from bridges.timesync.clock import TimeMapping, slewed
from bridges.timesync.coordinator import LATENCY_POLICIES, Coordinator, Expected
from bridges.timesync.errors import TimeSyncError
from bridges.timesync.messages import NAME
from bridges.v2x import EPOCH
from master.hooks import Hook, Outcome, RunContext
from master.scenario.tables import Table, did_you_mean

log = logging.getLogger(__name__)

TRANSPORTS = ("zenoh", "udp", "memory")
BRIDGE_KEYS = ("transport", "prefix", "listen", "connect", "group", "port", "options", "latency",
               "join_timeout_s", "heartbeat_s", "heartbeat_timeout_s", "on_refused", "camera_encoding")
PARTICIPANT_KEYS = ("role", "required", "timeout_s", "sync_every", "latencies", "command", "args", "env", "enabled")
_VALUE_REF = re.compile(r"\{([A-Za-z_][A-Za-z0-9_\-]*(?:\.[A-Za-z0-9_\-]+)+)\}")  # {can.port}: a scenario value
ON_REFUSED = ("wait", "fail")
_PREFIX = re.compile(r"^[A-Za-z0-9_.\-]+(/[A-Za-z0-9_.\-]+)*$")
MAP_PERIOD_S = 1.0  # realtime: republish the mapping this often (wall seconds)
REANCHOR_S = 0.05  # realtime without a pacer (hooks driven by hand): re-anchor when the steps drift this far
STOP_GRACE_S = 5.0  # wall seconds a started participant gets to exit after a completed run
FAILED_GRACE_S = 1.0  # ... after a failed one (it may be the one that hung)


@dataclass
class BridgeSpec:
    transport: str = "zenoh"
    prefix: str | None = None  # None: made unique per run
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    group: str | None = None
    port: int | None = None
    options: dict[str, Any] = field(default_factory=dict)
    latency: str = "fixed"
    join_timeout_s: float = 10.0
    heartbeat_s: float = 0.5
    heartbeat_timeout_s: float = 3.0
    on_refused: str = "wait"
    camera_encoding: str = "raw"  # camera frames on the bus: raw, jpeg or off

    def bus_options(self) -> dict[str, Any]:
        out = dict(self.options)
        for k in ("listen", "connect"):
            if getattr(self, k):
                out[k] = list(getattr(self, k))
        for k in ("group", "port"):
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        return out

    def resolved(self) -> dict[str, Any]:
        return {"transport": self.transport, "prefix": self.prefix or "auto", **self.bus_options(),
                "latency": self.latency, "join_timeout_s": self.join_timeout_s, "heartbeat_s": self.heartbeat_s,
                "heartbeat_timeout_s": self.heartbeat_timeout_s, "on_refused": self.on_refused,
                "camera_encoding": self.camera_encoding}


@dataclass
class ParticipantSpec:
    name: str
    role: str | None = None
    required: bool = True
    timeout_s: float = 5.0
    sync_every: int = 1
    latencies: dict[str, float] = field(default_factory=dict)
    command: list[str] | None = None
    args: list[str] = field(default_factory=list)  # appended to command
    env: dict[str, str] = field(default_factory=dict)
    enabled: bool = True

    def expected(self) -> Expected:
        return Expected(self.name, self.role, self.required, self.timeout_s, self.sync_every, dict(self.latencies))

    def resolved(self) -> dict[str, Any]:
        out = {"role": self.role, "required": self.required, "timeout_s": self.timeout_s,
               "sync_every": self.sync_every, "latencies": dict(self.latencies)}
        if self.command:
            out["command"] = list(self.command)
        if self.args:
            out["args"] = list(self.args)
        if self.env:
            out["env"] = dict(self.env)
        return {k: v for k, v in out.items() if v is not None}


@dataclass
class ParticipantsSpec:
    bridge: BridgeSpec
    participants: dict[str, ParticipantSpec]
    base_dir: Path = Path(".")

    def resolved(self) -> dict[str, Any]:
        return {"bridge": self.bridge.resolved(),
                "participants": {n: p.resolved() for n, p in self.participants.items()}}


# -- validation ----------------------------------------------------------------------
def read_section(tables: dict[str, Any], context) -> ParticipantsSpec:
    """The reader of the `[bridge]` and `[participants.NAME]` section (master.scenario.sections)."""
    return parse_participants(tables.get("bridge"), tables.get("participants"), context.base_dir, context.problem,
                              context.raw)


def parse_participants(bridge: Any, participants: Any, base_dir: Path,
                       problem: Callable[[str, str], None], raw: dict[str, Any] | None = None) -> ParticipantsSpec:
    """Validate `[bridge]` and `[participants.NAME]`; every problem goes to `problem(key, message)`."""
    b = _parse_bridge(Table(bridge if bridge is not None else {}, "bridge", problem))
    members = Table(participants if participants is not None else {}, "participants", problem,
                    expected="a table of [participants.NAME] tables")
    specs: dict[str, ParticipantSpec] = {}
    for name in members.raw:
        spec = _parse_participant(members, name, raw or {})
        if spec is None or not spec.enabled:  # enabled = false: not started, not waited for (a variant
            continue                          # of a scenario without this app, e.g. ima_no_cps.toml)
        if spec.command and b.transport == "memory":
            members.problem(f"{name}.command", "the memory transport only reaches this process; "
                                               "a started participant needs transport = \"zenoh\" or \"udp\"")
        specs[name] = spec
    return ParticipantsSpec(b, specs, base_dir)


def _seconds(t: Table, key: str, default: float, allow_zero: bool = False) -> float:
    """Wall-clock seconds, at most a day."""
    return t.number(key, default, low=0, low_open=not allow_zero, high=86400,
                    expected=f"wall-clock seconds {'>= 0' if allow_zero else '> 0'} (at most 86400)")


def _parse_bridge(t: Table) -> BridgeSpec:
    if not t.ok:  # not a table
        return BridgeSpec()
    t.unknown_keys(BRIDGE_KEYS)
    d = BridgeSpec()
    spec = BridgeSpec(listen=t.endpoints("listen"), connect=t.endpoints("connect"))
    spec.transport = t.choice("transport", TRANSPORTS, d.transport)
    spec.prefix = t.string("prefix", None, pattern=_PREFIX,
                           expected="key chunks like \"v2i/run1\" (letters, digits, _ . -; no wildcards, "
                                    "no leading or trailing /)")
    spec.group = t.string("group", None, expected="a multicast group address string")
    spec.port = t.number("port", None, low=1, high=65535, integer=True, expected="a port number 1..65535")
    spec.options = dict(t.sub("options", "a table of transport options").raw)
    spec.latency = t.choice("latency", LATENCY_POLICIES, d.latency)
    spec.on_refused = t.choice("on_refused", ON_REFUSED, d.on_refused)
    spec.camera_encoding = t.choice("camera_encoding", ("raw", "jpeg", "off"), d.camera_encoding)
    spec.join_timeout_s = _seconds(t, "join_timeout_s", d.join_timeout_s)
    spec.heartbeat_s = _seconds(t, "heartbeat_s", d.heartbeat_s)
    spec.heartbeat_timeout_s = _seconds(t, "heartbeat_timeout_s", d.heartbeat_timeout_s)
    if spec.heartbeat_timeout_s <= spec.heartbeat_s:
        t.problem("heartbeat_timeout_s", f"must be longer than heartbeat_s ({spec.heartbeat_s:g} s), "
                                         f"got {spec.heartbeat_timeout_s:g}")
    return spec


def _parse_participant(members: Table, name: str, raw: dict[str, Any]) -> ParticipantSpec | None:
    if not NAME.match(name):
        members.problem(name, "participant names must be letters, digits, _ or - (at most 64; they are key chunks)")
        return None
    t = members.sub(name)
    if not t.ok:
        return None
    t.unknown_keys(PARTICIPANT_KEYS)
    spec = ParticipantSpec(name)
    spec.enabled = t.boolean("enabled", True)
    spec.role = t.string("role", None, expected="a role name such as \"rsu_app\"")
    spec.required = t.boolean("required", spec.required)
    spec.timeout_s = _seconds(t, "timeout_s", spec.timeout_s)
    spec.sync_every = t.number("sync_every", spec.sync_every, low=1, integer=True,
                               expected="an integer >= 1 (steps between ticks)")
    latencies = t.sub("latencies", "a table of stage = simulated seconds")
    for stage in latencies.raw:
        seconds = latencies.number(stage, None, low=0, expected="simulated seconds >= 0")
        if seconds is not None:
            spec.latencies[stage] = seconds
    spec.command = t.strings("command", None, nonempty=True,
                             expected="a non-empty list of strings (\"{python}\" is this Python)")
    spec.args = t.strings("args", [], expected="a list of strings (appended to command)")
    if spec.args and not spec.command:
        t.problem("args", "appended to command: this participant has no command")
    spec.command = _with_values(t, "command", spec.command, raw)
    spec.args = _with_values(t, "args", spec.args, raw) or []
    env = t.get("env", {})
    if not isinstance(env, dict) or not all(isinstance(v, str) for v in env.values()):
        t.problem("env", f"expected a table of NAME = \"string\", got {env!r}")
    else:
        spec.env = dict(env)
    return spec


def _with_values(t: Table, key: str, words: list[str] | None, raw: dict[str, Any]) -> list[str] | None:
    """`words` with each {table.key} replaced by that value of the scenario, so an app's flag and the
    scenario cannot disagree (`"--can-port", "{can.port}"`) and a sweep changes both at once."""
    if not words:
        return words
    out = []
    for i, word in enumerate(words):
        try:
            out.append(_VALUE_REF.sub(lambda m: _scenario_value(raw, m.group(1)), word))
        except LookupError as exc:
            t.problem(f"{key}[{i}]", str(exc))
            out.append(word)
    return out


def _scenario_value(raw: dict[str, Any], dotted: str) -> str:
    """The scenario's value at `dotted` as command-line text; LookupError saying why there is none."""
    node: Any = raw
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            hint = did_you_mean(part, node) if isinstance(node, dict) else None
            raise LookupError(f"{{{dotted}}} names no value of the scenario" + (f"; {hint}" if hint else ""))
        node = node[part]
    if isinstance(node, (dict, list)):
        raise LookupError(f"{{{dotted}}} is a {'table' if isinstance(node, dict) else 'list'}, not a single value")
    return str(node).lower() if isinstance(node, bool) else str(node)


# -- the bridge in the master loop ----------------------------------------------------------
def run_prefix(spec: ParticipantsSpec, run_name: str) -> str:
    """The bus key prefix of one run: the scenario's, or one of its own so parallel runs never hear each other."""
    safe = re.sub(r"[^A-Za-z0-9_.\-]", "_", run_name) or "run"
    return spec.bridge.prefix or f"v2i/{safe}-{uuid.uuid4().hex[:8]}"


def open_run_bus(bridge: BridgeSpec, prefix: str):
    """The run's bus (the master owns it; its hooks share it); TimeSyncError naming [bridge] when it cannot open."""
    from bridges.transport import TransportError, open_bus

    try:
        return open_bus(bridge.transport, prefix=prefix, sender="master", **bridge.bus_options())
    except (TransportError, OSError, ValueError, TypeError) as exc:  # port taken, bad endpoint, bad option
        raise TimeSyncError(f"[bridge]: cannot open the {bridge.transport} bus ({bridge.bus_options()}): {exc}") \
            from exc


class ParticipantBridge(Hook):
    """Time protocol of one run, as the first manipulator of the loop; inert (and free) without participants.

    It opens after the serial and CAN gateways, so the apps it starts find their ports in their environment.
    """

    name = "participants"
    opens_after = ("serial", "can")

    def __init__(self, spec: ParticipantsSpec | None, mode: str, rtf: float, run_name: str, quiet: bool = True,
                 world: dict[str, Any] | None = None):
        """`world`: what the join reply tells every app of the scenario's world (WorldLayout.describe();
        without a [world] table, the default geodetic origin)."""
        self.spec, self.mode, self.rtf, self.quiet = spec, mode, rtf, quiet
        self.world = dict(world) if world is not None else {"origin": GeoOrigin().to_dict()}
        self.serial_urls: dict[str, str] = {}  # [serial.NAME] -> its pyserial URL, once the ports are open
        self.j2735_edition: str | None = None  # [v2x] j2735_edition, given to started apps
        self.prefix = run_prefix(spec, run_name) if spec is not None else None
        self.bus = None
        self.coordinator: Coordinator | None = None
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.exits: dict[str, dict[str, Any]] = {}
        self._ended = False
        self._step = 0.0
        self._mapping: TimeMapping | None = None
        self._pacer = None  # realtime: the loop's Pacer, whose schedule the mapping follows
        self._shift = 0.0
        self._schedule: TimeMapping | None = None  # realtime: the pacer's schedule, which the mapping slews to
        self._map_sent = 0
        self._last_check = 0.0

    def __bool__(self) -> bool:
        """A [bridge] table opens the bus, with or without time-regulated participants."""
        return self.spec is not None

    # -- hooks ---------------------------------------------------------------------------
    def open(self, ctx: RunContext) -> dict[str, Any]:
        b = self.spec.bridge
        t0, run_dir = ctx.t0, ctx.run_dir
        self._step = ctx.h
        self.serial_urls = dict(ctx.serial_urls)
        self.j2735_edition = getattr(getattr(ctx.scenario, "v2x", None), "j2735_edition", None)
        # the Unix time simulation time t0 stands for: apps date their J2735/1609.2 messages from it
        self.world[EPOCH] = time.time() - t0
        self.bus = ctx.bus
        self.coordinator = Coordinator(
            self.bus, [p.expected() for p in self.spec.participants.values()], mode=self.mode,
            latency_policy=b.latency, heartbeat_s=b.heartbeat_s, heartbeat_timeout_s=b.heartbeat_timeout_s,
            master_timeout_s=max(10.0, 4 * b.heartbeat_timeout_s), on_refused=b.on_refused, poll=self._poll,
            world=self.world)
        self.coordinator.start()
        if self.mode == "realtime":
            ctx.clock = self.clock_time
            self._pacer = ctx.pacer
        for p in self.spec.participants.values():
            if p.command:
                self._start(p, Path(run_dir))
        started = [p.name for p in self.spec.participants.values() if p.command and not p.required]
        self.coordinator.wait_for_participants(b.join_timeout_s, optional=started)
        return self.report()

    def before_step(self, k: int, t: float) -> None:
        if self.mode == "lockstep":
            self.coordinator.tick(k, t, self._step)
            return
        now = self.coordinator.clock_ns()
        m = self._mapping
        pacer = self._pacer
        if pacer is not None:
            # the run clock is the pacer's schedule: it moves only when the schedule does (the slip and
            # skip overrun policies), never because a step is late, so the apps' clock and the master's
            # stamps never jump back while the loop lags (lateness is reported as deadline misses)
            # a schedule that moved back (slip) is slewed to, never stepped to: the run clock only runs forward
            follow = m
            if m is None or pacer.shift != self._shift:
                self._shift = pacer.shift
                late_ns = round((pacer.clock() - pacer.scheduled(k)) * 1e9)
                self._schedule = TimeMapping(t, now - late_ns, self.rtf)
                follow = slewed(m, self._schedule, now)
            elif m is not self._schedule and m.sim_time(now) <= self._schedule.sim_time(now):
                follow = self._schedule  # the slewed clock has met the schedule
            if follow is not m:
                self._mapping = m = follow
                self._map_sent = 0
        elif m is None or abs(now - m.master_ns(t)) > REANCHOR_S * 1e9:
            self._mapping = m = TimeMapping(t, now, self.rtf)
            self._map_sent = 0
        if now - self._map_sent >= MAP_PERIOD_S * 1e9:
            self.coordinator.publish_mapping(m.t_sim0, m.wall0_ns, m.rtf)
            self._map_sent = now
        if any(k % p.sync_every == 0 for p in self.spec.participants.values()):
            self.coordinator.announce(k, t, self._step)
        if time.monotonic() - self._last_check > 0.05:
            self._last_check = time.monotonic()
            self.coordinator.check()

    def clock_time(self) -> float | None:
        """Realtime: the run clock's simulation time now (the mapping the apps follow); None before the
        first mapping or in lockstep."""
        m = self._mapping
        if m is None or self.coordinator is None:
            return None
        return m.sim_time(self.coordinator.clock_ns())

    def after_step(self, k: int, t_next: float) -> None:
        """Nothing: participants see the state of t_next at the next tick."""

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        status = outcome.status if outcome is not None else "completed"
        error = outcome.error if outcome is not None else None
        if status == "stopped":  # a stop condition ended the run: for the apps, it ended normally
            status, error = "completed", outcome.stop_reason
        self._ended = True
        if self.coordinator is not None:
            self.coordinator.end(status, error or "")
        self._stop_processes(STOP_GRACE_S if status == "completed" else FAILED_GRACE_S)
        if self.coordinator is not None:
            self.coordinator.close()
        report = self.report()
        if self.bus is not None:
            try:
                report["bus"] = self.bus.stats()
            except Exception as exc:  # stats are a nicety; the bus may be half gone
                report["bus"] = {"error": str(exc)}
        return report  # the bus is the master's: it closes it after every hook

    def report(self) -> dict[str, Any]:
        b = self.spec.bridge
        out = {"transport": b.transport, "prefix": self.prefix, "endpoints": b.bus_options()}
        if self.coordinator is not None:
            out.update(self.coordinator.report())
        for name, member in out.get("members", {}).items():
            if name in self.logs:
                member["log"] = self.logs[name].name
            if name in self.exits:
                member["process"] = self.exits[name]
        return out

    # -- started participants ---------------------------------------------------------------------
    def child_env(self, p: ParticipantSpec) -> dict[str, str]:
        b = self.spec.bridge
        options = b.bus_options()
        options.pop("listen", None)  # the master listens; a child connects
        connect = list(b.connect) or [_reachable(e) for e in b.listen]
        options.pop("connect", None)
        env = dict(os.environ)
        env.update({"V2I_BUS": b.transport, "V2I_PREFIX": self.prefix, "V2I_CONNECT": ",".join(connect),
                    "V2I_BUS_OPTIONS": json.dumps(options), "V2I_NAME": p.name, "V2I_ROLE": p.role or "",
                    "PYTHONUNBUFFERED": "1", lifeline.ENV: str(os.getpid())})
        for name, url in self.serial_urls.items():  # the run's serial ports, e.g. V2I_SERIAL_TLC
            env[serial_env(name)] = _reachable(url)
        if self.j2735_edition:  # the apps' default_codec() speaks the scenario's J2735 edition
            env["V2I_J2735_EDITION"] = self.j2735_edition
        env.update(p.env)
        return env

    def _start(self, p: ParticipantSpec, run_dir: Path) -> None:
        words = {"{python}": sys.executable, "{name}": p.name, "{run}": str(run_dir.resolve())}
        argv = []
        for c in [*p.command, *p.args]:
            for placeholder, value in words.items():
                c = c.replace(placeholder, value)
            argv.append(c)
        path = run_dir / f"participant-{p.name}.log"
        self.logs[p.name] = path
        with open(path, "wb") as out:
            try:
                self.procs[p.name] = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                                      env=self.child_env(p), cwd=self.spec.base_dir)
            except OSError as exc:
                self.coordinator.lose(p.name, f"could not start {argv[0]!r}: {exc}")
                return
        log.info("started participant '%s' (pid %d): %s", p.name, self.procs[p.name].pid, " ".join(argv))

    def _poll(self) -> None:
        """Called while the coordinator waits: a started participant whose process died is lost now."""
        if self._ended:
            return
        for name, proc in self.procs.items():
            rc = proc.poll()
            if rc is None or name in self.exits:
                continue
            self.exits[name] = {"pid": proc.pid, "returncode": rc, "during_run": True}
            refusals = [r["reason"] for r in self.coordinator.refused if r["name"] == name]
            why = f"; it was refused: {refusals[-1]}" if refusals else ""
            self.coordinator.lose(name, f"its process exited with code {rc} "
                                        f"(see {self.logs[name].name} in the run folder){why}")

    def _stop_processes(self, grace_s: float) -> None:
        deadline = time.monotonic() + grace_s
        for name, proc in self.procs.items():
            how = "exited"
            try:
                proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                how = "terminated"
                proc.terminate()
                try:
                    proc.wait(timeout=2.0)
                except subprocess.TimeoutExpired:
                    how = "killed"
                    proc.kill()
                    proc.wait()
            entry = self.exits.setdefault(name, {"pid": proc.pid, "returncode": proc.returncode, "during_run": False})
            entry.update(returncode=proc.returncode, stopped=how)


def serial_env(name: str) -> str:
    """The environment variable that gives a started app the URL of serial port `name`."""
    return "V2I_SERIAL_" + re.sub(r"[^A-Za-z0-9]", "_", name).upper()


def _reachable(endpoint: str) -> str:
    """A listen endpoint as a local child can connect to it (0.0.0.0 / [::] -> loopback)."""
    return endpoint.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]")
