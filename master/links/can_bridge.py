"""The CAN bridge: the AV computer drives a VehicleDynamics FMU over CAN frames from a DBC.

The master plays the vehicle's drive-by-wire gateway. The AV app sends
``AV_Command`` (acceleration, steering angle, mode) on a python-can bus and reads
``AV_Status`` (speed, yaw rate, acceleration, mode) back, with the same code it
would run against a real vehicle bus (``bridges/can``).

Scenario file::

    [can]
    vehicle = "cav"                 # the VehicleDynamics instance the commands drive
    interface = "udp_multicast"     # or "virtual" (one process), "socketcan", "pcan", ...
    channel = "239.74.163.2"        # multicast group / bus channel (default per interface)
    port = 43113                    # udp_multicast only: another port keeps parallel runs apart
    iface = "127.0.0.1"             # udp_multicast only: the interface's address (default: this host only)
    # bitrate = 500000              # real buses
    status_rate_hz = 50.0           # AV_Status rate; its period must be a multiple of the step
                                    # (with sync = "echo" in lockstep: at least two of the vehicle's steps)
    command_timeout_s = 0.1         # simulated s without a new command before the fallback
    on_timeout = "brake"            # "brake" (timeout_accel), "zero_accel", "hold" or "manual"
    timeout_accel = -4.0            # m/s^2 of the "brake" fallback
    estop_accel = -8.0              # m/s^2 applied while Mode = EMERGENCY_STOP
    sync = "echo"                   # "echo" (lockstep default, deterministic), "drain" or "free"
    sync_timeout_s = 2.0            # wall s the master waits for the answer to a status frame
    connect_timeout_s = 0.0         # wall s to wait for the first command before step 0
    # dbc = "my_vehicle.dbc"        # a DBC with the same message/signal names (default: bridges/can/cav.dbc)
    # accel_input, steer_input, reverse_input, speed_output, yaw_rate_output, accel_output:
    #                                 the FMU variables (defaults: accel_cmd, steer_cmd, reverse, v, yaw_rate, a)

Timing rule ("t + one step"): a command answering the AV_Status of time t_s is
applied at t_s + h, never earlier, whatever the wall-clock speed of the app.
``sync`` chooses how the master gets there: ``"echo"`` (lockstep default,
bit-for-bit reproducible: the master waits up to ``sync_timeout_s`` wall seconds
for the answer), ``"drain"`` (read the bus at each communication point, for the
time protocol) or ``"free"`` (the latest command received, as on a real bus;
echo becomes free in realtime mode). The rules themselves, and why they make a
run reproducible, are in ``master.links.can_gateway``: the pure core that decides what
drives the vehicle when. This module is its hook in the loop: the bus, the
receive thread, frame checks, the wall-clock wait, the FMU and the logs.

Whatever the sync, what was applied when is in ``can-applied.csv`` (one row per change
of the FMU's inputs: time, event, mode, values, counter, echo, basis time, and
`t_clock`, the time on the run clock the apps stamp with: = t in lockstep, the
published sim/wall mapping's time in realtime), bad
frames are tallied by reason in metadata and the first of each reason is logged
with its bytes in ``can-events.jsonl``; nothing from the bus stops a run.
"""
from __future__ import annotations

import csv
import math
import sys
import threading
import time
from collections import Counter as Tally
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import can

from bridges.can.bus import DEFAULT_IFACE, BusConfig, open_bus
from bridges.can.codec import (STATUS, CavCodec, CavCommand, CavHeartbeat, CavStatus, FrameError,
                               RollingCounter, RxChecker)
from master.links.can_gateway import TIMING_RULES, Actuation, Gateway
from master.events import EventLog
from master.errors import ScenarioError, SimulationError
from master.hooks import Hook, Outcome, RunContext
from master.scenario.tables import Table

ON_TIMEOUT = ("brake", "zero_accel", "hold", "manual")
SYNC_MODES = ("echo", "drain", "free")
CAN_KEYS = ("vehicle", "interface", "channel", "port", "iface", "bitrate", "fd", "options", "status_rate_hz",
            "command_timeout_s", "on_timeout", "timeout_accel", "estop_accel", "sync", "sync_timeout_s",
            "connect_timeout_s", "dbc", "accel_input", "steer_input", "reverse_input", "speed_output",
            "yaw_rate_output", "accel_output")
# key -> (default variable, causality, family, required)
_VARIABLES = {"accel_input": ("accel_cmd", "input", "real", True),
              "steer_input": ("steer_cmd", "input", "real", True),
              "reverse_input": ("reverse", "input", "boolean", False),
              "speed_output": ("v", "output", "real", True),
              "yaw_rate_output": ("yaw_rate", "output", "real", True),
              "accel_output": ("a", "output", "real", True)}
MAX_DRAIN = 10_000  # frames one drain takes at most (a flooded bus cannot stall a step forever)
LOGGED_PER_REASON = 20  # first bad frames of each reason go to the event log; all are counted
_EPS = 1e-9
APPLIED_CSV = "can-applied.csv"
EVENTS_JSONL = "can-events.jsonl"


@dataclass
class CanConfig:
    vehicle: str
    bus: BusConfig = field(default_factory=BusConfig)
    status_rate_hz: float = 50.0
    command_timeout_s: float = 0.1
    on_timeout: str = "brake"
    timeout_accel: float = -4.0
    estop_accel: float = -8.0
    sync: str = "echo"
    sync_timeout_s: float = 2.0
    connect_timeout_s: float = 0.0
    dbc: Path | None = None
    variables: dict[str, str | None] = field(default_factory=lambda: {k: v[0] for k, v in _VARIABLES.items()})

    def resolved(self) -> dict[str, Any]:
        b = self.bus
        out: dict[str, Any] = {"vehicle": self.vehicle, "interface": b.interface, "channel": b.resolved_channel(),
                               "status_rate_hz": self.status_rate_hz, "command_timeout_s": self.command_timeout_s,
                               "on_timeout": self.on_timeout, "timeout_accel": self.timeout_accel,
                               "estop_accel": self.estop_accel, "sync": self.sync,
                               "sync_timeout_s": self.sync_timeout_s, "connect_timeout_s": self.connect_timeout_s,
                               **{k: v for k, v in self.variables.items() if v}}
        if b.interface == "udp_multicast":
            out["port"] = b.kwargs()["port"]
            out["iface"] = b.iface
        if b.bitrate is not None:
            out["bitrate"] = b.bitrate
        if b.fd:
            out["fd"] = True
        if b.options:
            out["options"] = dict(b.options)
        if self.dbc is not None:
            out["dbc"] = str(self.dbc)
        return out


def read_section(value: Any, context) -> CanConfig | None:
    """The `[can]` section's reader (master.scenario.sections)."""
    return parse_can(value, context.instances, connections=context.connections, step=context.step,
                     base_dir=context.base_dir, path=context.path, problem=context.problem,
                     mode=context.time.mode)


def parse_can(table: Any, instances: dict, *, connections=(), step: float | None = None,
              base_dir: Path | None = None, path: str | Path = "scenario",
              problem: Callable[[str, str], None] | None = None, mode: str = "lockstep") -> CanConfig | None:
    """Validate the `[can]` table (`mode`: the run's time mode, `[time] mode`).

    Every fault is named by its key (``can.status_rate_hz: ...``). With `problem`
    (the scenario loader's collector) faults go there and None is returned;
    without it a ScenarioError listing them all is raised.
    """
    problems: list[str] = []

    def bad(key: str, reason: str) -> None:
        if problem is not None:
            problem(key, reason)
        else:
            problems.append(f"{key}: {reason}")

    config = _parse(Table(table, "can", bad), instances, connections, step, base_dir, mode)
    if problems:
        raise ScenarioError(path, problems)
    return config


def _parse(t: Table, instances, connections, step, base_dir, mode="lockstep") -> CanConfig | None:
    if not t.ok:  # not a table
        return None
    t.unknown_keys(CAN_KEYS)
    inst = t.instance("vehicle", instances, "the name of the vehicle FMU instance the commands drive")
    variables: dict[str, str | None] = {}
    driven = {(c.dst, c.dst_var): str(c) for c in connections}
    for key, (default, causality, fam, required) in _VARIABLES.items():
        name = variables[key] = t.fmu_variable(key, inst, causality=causality, family=fam, default=default,
                                               required=required)
        if inst is not None and name is not None and causality == "input" and (inst.name, name) in driven:
            t.problem(key, f"{inst.name}.{name} is already driven by {driven[(inst.name, name)]}")

    rate = t.number("status_rate_hz", 50.0, low=0.0, high=1000.0, low_open=True)
    timeout = t.number("command_timeout_s", 0.1, low=0.0, high=3600.0, low_open=True)
    timeout_accel = t.number("timeout_accel", -4.0, low=-100.0, high=0.0)
    estop_accel = t.number("estop_accel", -8.0, low=-100.0, high=0.0)
    if estop_accel >= 0:
        t.problem("estop_accel", "must be < 0 (a deceleration)")
    sync_timeout = t.number("sync_timeout_s", 2.0, low=0.0, high=3600.0, low_open=True)
    connect_timeout = t.number("connect_timeout_s", 0.0, low=0.0, high=3600.0)
    on_timeout = t.choice("on_timeout", ON_TIMEOUT, "brake")
    sync = t.choice("sync", SYNC_MODES, "echo")
    if step is not None and rate > 0:
        n = round(1.0 / (rate * step))
        if n < 1 or abs(n * step * rate - 1.0) > 1e-6:
            t.problem("status_rate_hz", f"the status period 1/{rate:g} s must be a whole number of steps of {step:g} s")
    if (sync == "echo" and mode == "lockstep" and "sync" not in t.failed and "status_rate_hz" not in t.failed
            and step is not None and rate > 0 and inst is not None
            and round(1.0 / (rate * step * inst.step_multiple)) <= 1):
        # echo waits at t_s + h for the answer to the status of t_s; a status every step sends the next one
        # (of t_s + h) first, which replaces the awaited one: the master would never wait (CanBridge.status_every)
        t.problem("status_rate_hz", f"{rate:g} Hz is a status every step of {inst.name} "
                                    f"({step * inst.step_multiple:g} s): with sync = \"echo\" the next status "
                                    "replaces the one whose answer is awaited, so the master never waits and the "
                                    "run is not reproducible; use at most half that rate, or sync = \"drain\" "
                                    "(with the time protocol) or \"free\"")
    if sync == "echo" and "sync" not in t.failed and timeout <= 1.0 / rate + (step or 0.0) - _EPS:
        t.problem("command_timeout_s", f"{timeout:g} s would time out between two answers: with sync = \"echo\" "
                                       f"a new command comes every status period ({1.0 / rate:g} s), so it must be "
                                       "longer than one status period plus one step")

    options = t.sub("options", "a table of can.Bus keyword arguments").raw
    fd = t.boolean("fd", False)
    interface = t.string("interface", "udp_multicast", expected="a python-can interface name")
    channel = t.get("channel")
    if channel is not None and not isinstance(channel, (str, int)) or isinstance(channel, bool):
        t.problem("channel", f"expected a string (or number), got {channel!r}")
        channel = None
    bus = BusConfig(interface, channel, t.get("bitrate"), t.get("port"), fd, dict(options),
                    t.get("iface", DEFAULT_IFACE))
    for key, reason in bus.problems():
        t.problem(key, reason)

    dbc = t.string("dbc", None, expected="a path to a .dbc file")
    if dbc is not None:
        dbc = Path(dbc).expanduser()
        if not dbc.is_absolute() and base_dir is not None:
            dbc = Path(base_dir) / dbc
        try:
            CavCodec(dbc)
        except ValueError as exc:
            t.problem("dbc", str(exc))
    if not t.ok or inst is None:
        return None
    return CanConfig(inst.name, bus, rate, timeout, on_timeout, timeout_accel, estop_accel, sync, sync_timeout,
                     connect_timeout, dbc, variables)


class CanBridge(Hook):
    """The gateway's hook in the loop: bus, receive thread, frame checks, echo wait, FMU and logs.

    Every decision (which command applies when, the timeout policy, the
    statistics of commands) is the pure core's, `master.links.can_gateway.Gateway`;
    this class feeds it what came off the bus and writes what it answers.
    """

    name = "can"

    def __init__(self, config: CanConfig | None, mode: str = "lockstep", quiet: bool = True):
        self.config = config
        self.mode = mode
        self.quiet = quiet
        self.sync = config.sync if config else "free"
        if self.sync == "echo" and mode != "lockstep":
            self.sync = "free"  # realtime: the master never waits for an app
        self.ready = threading.Event()  # set once the bus is open (tests and launchers wait on it)
        self.bus: can.BusABC | None = None
        self.codec: CavCodec | None = None
        self.gateway: Gateway | None = None
        self._cond = threading.Condition()
        self._inbox: deque[tuple[CavCommand, float]] = deque()  # valid commands not yet given to the gateway
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._events = None
        self._injector = None  # a second sender on the bus, opened by the first injected frame
        self._csv = None
        self._csv_file = None
        self._logged = Tally()
        self.stats: dict[str, Any] = {}

    def __bool__(self) -> bool:
        return self.config is not None

    # -- set-up ---------------------------------------------------------------------
    def open(self, ctx: RunContext) -> dict[str, Any]:
        cfg = self.config
        member = ctx.members[cfg.vehicle]
        fmu, multiple, t = member.fmu, member.multiple, ctx.t0
        self.fmu, self.multiple, self.h = fmu, multiple, ctx.h * multiple
        self.status_every = max(1, round(1.0 / (cfg.status_rate_hz * self.h)))
        codec = CavCodec(cfg.dbc)  # self.codec is set once everything close() needs exists
        self.checker = RxChecker(codec)

        def access(key: str, setter: bool):
            name = cfg.variables.get(key)
            if not name:
                return None
            return fmu.accessor(fmu.access_key(name), [fmu.variables[name].valueReference], setter=setter)

        self._set = {k: access(k, True) for k in ("accel_input", "steer_input", "reverse_input")}
        get_in = {k: access(k, False) for k in ("accel_input", "steer_input", "reverse_input")}
        self._get_out = [access(k, False) for k in ("speed_output", "yaw_rate_output", "accel_output")]
        baseline = (float(get_in["accel_input"]()[0]), float(get_in["steer_input"]()[0]),
                    bool(get_in["reverse_input"]()[0]) if get_in["reverse_input"] else False)
        self._limits = {s: codec.limits(STATUS, s) for s in ("Speed", "YawRate", "AccelActual")}

        self._status_counter = RollingCounter()
        self.gateway = Gateway(self.sync, self.h, t, baseline, command_timeout_s=cfg.command_timeout_s,
                               on_timeout=cfg.on_timeout, timeout_accel=cfg.timeout_accel,
                               estop_accel=cfg.estop_accel, log=self._log)
        self.rx_commands = 0  # valid commands taken off the bus by the receive thread
        run_dir = Path(ctx.run_dir)
        # the gateway's entries (commands_*, heartbeats, last_app_state, timeouts, fallback_s, actuation_age_s)
        # are refreshed from it at each snapshot; they stand here for the order of the metadata section
        self.stats = {"bus": cfg.bus.describe(), "dbc": str(codec.path), "vehicle": cfg.vehicle,
                      "sync": self.sync, "status_rate_hz": cfg.status_rate_hz, "status_every_steps": self.status_every,
                      "command_timeout_s": cfg.command_timeout_s, "on_timeout": cfg.on_timeout,
                      "timing_rule": TIMING_RULES[self.sync],
                      "step_s": self.h, "commands_received": 0, "commands_applied": 0, "commands_superseded": 0,
                      "commands_repeat_ignored": 0, "commands_unsynced": 0, "rejected": {}, "rejected_total": 0,
                      "counter_gaps": 0, "frames_ignored": {}, "heartbeats": 0, "last_app_state": None,
                      "status_sent": 0, "status_send_errors": 0, "status_saturated": {},
                      "sync_waits": 0, "sync_wait_wall_s": 0.0, "sync_timeouts": 0,
                      "timeouts": 0, "fallback_s": 0.0, "actuation_age_s": None,
                      "applied_log": APPLIED_CSV, "events": EVENTS_JSONL}
        self._ignored = Tally()
        self._saturated = Tally()
        self.codec = codec
        try:
            self.bus = open_bus(cfg.bus)
        except Exception as exc:  # python-can raises CanError, OSError, ImportError by interface
            raise SimulationError(cfg.vehicle, t, "can bridge open",
                                  f"cannot open {cfg.bus.describe()}: {type(exc).__name__}: {exc}") from exc
        self._events = EventLog(run_dir, EVENTS_JSONL, "w")
        self._stamp_time = ctx.stamp_time  # t_clock: realtime, the run clock the apps stamp CAN_COMMAND on
        self._csv_file = open(run_dir / APPLIED_CSV, "w", newline="", buffering=1)
        self._csv = csv.writer(self._csv_file)
        self._csv.writerow(["t", "event", "mode", "accel_cmd", "steer_cmd", "reverse", "counter", "status_echo",
                            "basis_t", "rx_time", "t_clock"])
        self._log({"t": t, "event": "open", "bus": cfg.bus.describe(), "sync": self.sync})
        if self.sync != "drain":
            self._thread = threading.Thread(target=self._receive, name="can-bridge", daemon=True)
            self._thread.start()
        with self._cond:
            initial = self.gateway.start()
        self._write(initial)
        self._send_status(t)
        self.ready.set()
        if not self.quiet:
            print(f"CAN bridge ({cfg.vehicle}): {cfg.bus.describe()}  [sync {self.sync}]", file=sys.stderr)
        if cfg.connect_timeout_s > 0:
            with self._cond:
                if not self._cond.wait_for(lambda: bool(self._inbox), cfg.connect_timeout_s):
                    self._log({"t": t, "event": "no_commands", "waited_s": cfg.connect_timeout_s})
        return self._snapshot()

    # -- receive thread -------------------------------------------------------------------
    def _receive(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(0.05)
            except Exception as exc:  # a broken adapter: log it, keep the run going
                self._log({"event": "recv_error", "error": f"{type(exc).__name__}: {exc}"})
                time.sleep(0.05)
                continue
            if msg is not None:
                self._handle(msg)

    def _drain(self) -> None:
        """sync = drain: take every frame already on the bus, in the master thread (no thread race)."""
        for _ in range(MAX_DRAIN):
            try:
                msg = self.bus.recv(0)
            except Exception as exc:
                self._log({"event": "recv_error", "error": f"{type(exc).__name__}: {exc}"})
                return
            if msg is None:
                return
            self._handle(msg)

    def _handle(self, msg: can.Message) -> None:
        """Check one frame; a valid command goes to the inbox, anything else is tallied."""
        if msg.arbitration_id == self.codec.status_id and not msg.is_extended_id:
            self._ignored["own AV_Status"] += 1  # our own frames (udp_multicast loops them back)
            return
        try:
            value = self.checker.check(msg)
        except FrameError as exc:
            if self._logged[exc.reason] < LOGGED_PER_REASON:
                self._logged[exc.reason] += 1
                self._log({"event": "rejected", "reason": exc.reason, "detail": exc.detail,
                           "id": msg.arbitration_id, "data": bytes(msg.data).hex(), "rx_time": msg.timestamp})
            return
        except Exception as exc:  # never let a frame kill the receiver
            self.checker.rejected["internal"] += 1
            self._log({"event": "rejected", "reason": "internal", "detail": f"{type(exc).__name__}: {exc}",
                       "id": msg.arbitration_id, "data": bytes(msg.data).hex()})
            return
        if isinstance(value, CavCommand):
            with self._cond:
                self._inbox.append((value, msg.timestamp or time.time()))
                self.rx_commands += 1
                self._cond.notify_all()
        elif isinstance(value, CavHeartbeat):
            with self._cond:
                self.gateway.heartbeat(value.state)
        else:
            self._ignored[type(value).__name__] += 1

    def wait_received(self, n: int, timeout: float) -> bool:
        """Block until the receive thread has taken `n` valid commands off the bus (tests, launchers)."""
        if self.sync == "drain":
            self._drain()
        with self._cond:
            return self._cond.wait_for(lambda: self.rx_commands >= n, timeout)

    # -- stepping (master thread) ------------------------------------------------------------
    def before_step(self, k: int, t: float) -> None:
        """Apply the command due at communication point t (waiting for it under sync = echo)."""
        if k % self.multiple:
            return
        if self.sync == "drain":
            self._drain()
        with self._cond:
            self._hand_over()
            due = self.gateway.awaited(t)
            if due is not None:  # sync = echo: the answer to the status of due.t applies here
                self.stats["sync_waits"] += 1
                w0 = time.monotonic()
                got = self._cond.wait_for(lambda: any(cmd.status_echo == due.counter for cmd, _ in self._inbox),
                                          self.config.sync_timeout_s)
                self.stats["sync_wait_wall_s"] += time.monotonic() - w0
                if not got:
                    self.gateway.lost_turn()
                    self.stats["sync_timeouts"] += 1
                    self._log({"t": t, "event": "sync_timeout", "status_counter": due.counter, "status_t": due.t,
                               "waited_s": self.config.sync_timeout_s})
                self._hand_over()
            actuation = self.gateway.reach(t)
        if actuation is not None:
            self._write(actuation)

    def _hand_over(self) -> None:
        """Give the gateway every command received so far, in bus order (called under the lock)."""
        while self._inbox:
            self.gateway.received(*self._inbox.popleft())

    def _write(self, a: Actuation) -> None:
        """Set the FMU's inputs (when they change) and log the row in can-applied.csv."""
        if a.inputs_changed:
            self._set["accel_input"]([float(a.accel)])
            self._set["steer_input"]([float(a.steer)])
            if self._set["reverse_input"] is not None:
                self._set["reverse_input"]([bool(a.reverse)])
        rx, cmd = a.source, a.command
        self._csv.writerow([repr(a.t), a.event, a.mode.name, repr(float(a.accel)), repr(float(a.steer)),
                            int(a.reverse), cmd.counter if cmd else "", cmd.status_echo if cmd else "",
                            repr(a.basis_t) if a.basis_t is not None else "",
                            repr(rx.rx_time) if rx is not None else "", repr(self._stamp_time(a.t))])

    def after_step(self, k: int, t_next: float) -> None:
        """Publish AV_Status at the status rate from the vehicle's outputs at the end of its step."""
        if k % self.multiple:
            return
        t_end = t_next + (self.multiple - 1) * (self.h / self.multiple)
        if (k // self.multiple + 1) % self.status_every == 0:
            self._send_status(t_end)

    def _send_status(self, t: float) -> None:
        values = []
        for getter, signal in zip(self._get_out, ("Speed", "YawRate", "AccelActual")):
            value = float(getter()[0])
            low, high = self._limits[signal]
            if not math.isfinite(value):
                self._saturated[signal] += 1
                value = 0.0
            elif value < low or value > high:
                self._saturated[signal] += 1
                value = min(max(value, low), high)
            values.append(value)
        with self._cond:
            mode, reverse = self.gateway.reported()
        counter = self._status_counter.next()
        data = self.codec.encode_status(CavStatus(*values, mode=mode, reverse=reverse, counter=counter))
        msg = can.Message(arbitration_id=self.codec.status_id, data=data, is_extended_id=False,
                          is_fd=self.config.bus.fd)
        try:
            self.bus.send(msg, timeout=0.1)
        except Exception as exc:  # a full or broken bus must not stop the run
            self.stats["status_send_errors"] += 1
            self._log({"t": t, "event": "send_error", "error": f"{type(exc).__name__}: {exc}"})
            return
        self.stats["status_sent"] += 1
        with self._cond:
            self.gateway.status_sent(counter, t)

    def inject(self, frames: list[tuple[int, bytes]]) -> int:
        """Send (arbitration id, data) frames on the gateway's bus from a sender of their own, as a faulty or
        hostile node on the same wires would (scenario events); the gateway tallies what it cannot use."""
        if self.codec is None:
            raise RuntimeError("the CAN bridge is not open")
        if self._injector is None:
            self._injector = open_bus(self.config.bus)
        sent = 0
        for arbitration_id, data in frames:
            self._injector.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False,
                                            dlc=len(data)))
            sent += 1
        self.stats["injected"] = self.stats.get("injected", 0) + sent
        return sent

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        """Stop receiving, close the bus and logs; the run's CAN statistics (empty if never opened)."""
        if self.codec is None:
            return {}
        if self._injector is not None:
            try:
                self._injector.shutdown()
            except Exception:
                pass
            self._injector = None
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self.bus is not None:
            try:
                self.bus.shutdown()
            except Exception:
                pass
            self.bus = None
        for f in (self._events, self._csv_file):
            if f is not None:
                f.close()  # EventLog.close and file.close: both idempotent
        self._events = self._csv_file = None
        return self._snapshot()

    def _snapshot(self) -> dict[str, Any]:
        with self._cond:
            self.stats.update(self.gateway.stats())
        s = dict(self.stats)
        s["rejected"] = dict(self.checker.rejected)
        s["rejected_total"] = sum(self.checker.rejected.values())
        s["counter_gaps"] = self.checker.counter_gaps
        s["frames_ignored"] = dict(self._ignored)
        s["status_saturated"] = dict(self._saturated)
        return s

    def _log(self, event: dict[str, Any]) -> None:
        events = self._events
        if events is not None:  # EventLog ignores lines after close (the receive thread may still log)
            events(event)


__all__ = ["CanConfig", "CanBridge", "parse_can", "ON_TIMEOUT", "SYNC_MODES", "CAN_KEYS"]
