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

Timing rule ("t + one step"). CAN frames carry no simulation time, so the
bridge ties each command to the status frame it answers: every AV_Status has
an 8-bit Counter, every AV_Command echoes the Counter of the status it was
computed from (``StatusEcho``). A status sent at simulation time t_s (after the
step that ends at t_s) is answered by a command that is applied at the
communication point t_s + h (h: the vehicle's communication step), never
earlier, whatever the wall-clock speed of the app:

* ``sync = "echo"`` (lockstep default): before stepping from t_s + h, the master
  waits (up to ``sync_timeout_s`` wall seconds) until the answer to the status of
  t_s has been received; an answer that arrives before the master has even
  finished the step from t_s is held back until t_s + h. The master and the app
  therefore overlap by one step (the master steps [t_s, t_s+h) while the app
  computes), and the app's compute time counts as exactly one step of simulated
  actuation latency: runs are bit-for-bit reproducible. Contract for the app: one
  AV_Command per AV_Status received (further commands echoing the same status
  are counted as repeats and not applied). A silent app loses its turn after
  ``sync_timeout_s``; the master then runs free until a command arrives again,
  and the simulated ``command_timeout_s`` policy takes over.
* ``sync = "drain"`` (with the time protocol, [participants]): no receive thread;
  at each communication point the master reads every frame already on the bus
  and applies the latest command there. Deterministic when something else orders
  the app and the master: an app that sends its AV_Command before it acknowledges
  the tick, with a master that waits for the acknowledgements before this point,
  has its command applied at this point (on one host: the datagram is in the
  socket before the acknowledgement leaves; across hosts the two paths may race).
* ``sync = "free"`` (echo becomes free in realtime mode, for HIL): the latest valid command
  received before a communication point is applied there, as a gateway on a
  real bus would. The echo still gives each command's basis time, so the run
  records its actuation age t_applied - t_status.

Either way, what was applied when is in ``can-applied.csv`` (one row per change
of the FMU's inputs: time, event, mode, values, counter, echo, basis time), bad
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
from bridges.can.codec import (STATUS, CavCodec, CavCommand, CavHeartbeat, CavStatus, FrameError, Mode,
                               RollingCounter, RxChecker)
from master.events import EventLog
from master.errors import ScenarioError, SimulationError
from master.fmu_variables import family

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


def parse_can(table: Any, instances: dict, *, connections=(), step: float | None = None,
              base_dir: Path | None = None, path: str | Path = "scenario",
              problem: Callable[[str, str], None] | None = None) -> CanConfig | None:
    """Validate the `[can]` table.

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

    config = _parse(table, instances, connections, step, base_dir, bad)
    if problems:
        raise ScenarioError(path, problems)
    return config


def _parse(table, instances, connections, step, base_dir, bad) -> CanConfig | None:
    if not isinstance(table, dict):
        bad("can", f"expected a table, got {type(table).__name__}")
        return None
    ok = True

    def fail(key: str, reason: str) -> None:
        nonlocal ok
        ok = False
        bad(f"can.{key}", reason)

    for k in table:
        if k not in CAN_KEYS:
            fail(k, f"unknown key (expected one of: {', '.join(CAN_KEYS)})")
    vehicle = table.get("vehicle")
    inst = None
    if not isinstance(vehicle, str) or not vehicle:
        fail("vehicle", "required: the name of the vehicle FMU instance the commands drive")
    elif vehicle not in instances:
        fail("vehicle", f"unknown instance {vehicle!r} (instances: {', '.join(instances) or 'none'})")
    else:
        inst = instances[vehicle]

    variables: dict[str, str | None] = {}
    driven = {(c.dst, c.dst_var): str(c) for c in connections}
    for key, (default, causality, fam, required) in _VARIABLES.items():
        name = table.get(key, default)
        if not isinstance(name, str) or not name:
            fail(key, f"expected a variable name, got {name!r}")
            continue
        variables[key] = name
        if inst is None:
            continue
        var = inst.variables.get(name)
        if var is None:
            if not required and key not in table:
                variables[key] = None  # optional default the FMU does not have
                continue
            fail(key, f"unknown variable {vehicle}.{name}")
        elif var.causality != causality or family(var.type) != fam:
            fail(key, f"{vehicle}.{name} is a {var.causality} of type {var.type}; expected a {fam} {causality}")
        elif causality == "input" and (vehicle, name) in driven:
            fail(key, f"{vehicle}.{name} is already driven by {driven[(vehicle, name)]}")

    def number(key: str, default: float, low: float, high: float, low_open: bool = False) -> float:
        value = table.get(key, default)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                or value < low or value > high or (low_open and value == low):
            fail(key, f"expected a number in {'(' if low_open else '['}{low}, {high}], got {value!r}")
            return default
        return float(value)

    rate = number("status_rate_hz", 50.0, 0.0, 1000.0, low_open=True)
    timeout = number("command_timeout_s", 0.1, 0.0, 3600.0, low_open=True)
    timeout_accel = number("timeout_accel", -4.0, -100.0, 0.0)
    estop_accel = number("estop_accel", -8.0, -100.0, 0.0)
    if estop_accel >= 0:
        fail("estop_accel", "must be < 0 (a deceleration)")
    sync_timeout = number("sync_timeout_s", 2.0, 0.0, 3600.0, low_open=True)
    connect_timeout = number("connect_timeout_s", 0.0, 0.0, 3600.0)
    on_timeout = table.get("on_timeout", "brake")
    if on_timeout not in ON_TIMEOUT:
        fail("on_timeout", f"expected one of {', '.join(ON_TIMEOUT)}, got {on_timeout!r}")
    sync = table.get("sync", "echo")
    if sync not in SYNC_MODES:
        fail("sync", f"expected one of {', '.join(SYNC_MODES)}, got {sync!r}")
    if step is not None and rate > 0:
        n = round(1.0 / (rate * step))
        if n < 1 or abs(n * step * rate - 1.0) > 1e-6:
            fail("status_rate_hz", f"the status period 1/{rate:g} s must be a whole number of steps of {step:g} s")
    if sync == "echo" and timeout <= 1.0 / rate + (step or 0.0) - _EPS:
        fail("command_timeout_s", f"{timeout:g} s would time out between two answers: with sync = \"echo\" a new "
                                  f"command comes every status period ({1.0 / rate:g} s), so it must be longer "
                                  "than one status period plus one step")

    options = table.get("options", {})
    if not isinstance(options, dict):
        fail("options", f"expected a table of can.Bus keyword arguments, got {type(options).__name__}")
        options = {}
    fd = table.get("fd", False)
    if not isinstance(fd, bool):
        fail("fd", f"expected true or false, got {fd!r}")
        fd = False
    interface = table.get("interface", "udp_multicast")
    channel = table.get("channel")
    if not isinstance(interface, str):
        fail("interface", f"expected a python-can interface name, got {interface!r}")
        interface = "udp_multicast"
    if channel is not None and not isinstance(channel, (str, int)) or isinstance(channel, bool):
        fail("channel", f"expected a string (or number), got {channel!r}")
        channel = None
    bus = BusConfig(interface, channel, table.get("bitrate"), table.get("port"), fd, dict(options),
                    table.get("iface", DEFAULT_IFACE))
    for key, reason in bus.problems():
        fail(key, reason)

    dbc = table.get("dbc")
    if dbc is not None:
        if not isinstance(dbc, str) or not dbc:
            fail("dbc", f"expected a path to a .dbc file, got {dbc!r}")
            dbc = None
        else:
            dbc = Path(dbc).expanduser()
            if not dbc.is_absolute() and base_dir is not None:
                dbc = Path(base_dir) / dbc
            try:
                CavCodec(dbc)
            except ValueError as exc:
                fail("dbc", str(exc))
    if not ok or inst is None:
        return None
    return CanConfig(vehicle, bus, rate, timeout, on_timeout, timeout_accel, estop_accel, sync, sync_timeout,
                     connect_timeout, dbc, variables)


_RULES = {"echo": "a command answering the AV_Status of time t is applied at t + h",
          "drain": "every command on the bus when the master reaches communication point t is applied at t "
                   "(read in the master thread, so none is missed by a thread race)",
          "free": "the latest valid command received before a communication point is applied there"}


@dataclass
class _Rx:
    """A valid command as received: its bus timestamp and the sim time of the status it answers."""

    cmd: CavCommand
    rx_time: float
    basis_t: float | None = None  # sim time of the AV_Status it echoes (None: unknown echo)
    hold_until: float | None = None  # echo: not applied before basis_t + h


class CanBridge:
    """The gateway: a receive thread tallies frames; the master thread applies and reports at step points."""

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
        self._cond = threading.Condition()
        self._inbox: deque[_Rx] = deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._events = None
        self._csv = None
        self._csv_file = None
        self._logged = Tally()
        self.stats: dict[str, Any] = {}

    def __bool__(self) -> bool:
        return self.config is not None

    # -- set-up ---------------------------------------------------------------------
    def open(self, members: dict[str, tuple[Any, int]], run_dir: Path, t: float, step: float) -> dict[str, Any]:
        cfg = self.config
        fmu, multiple = members[cfg.vehicle]
        self.fmu, self.multiple, self.h = fmu, multiple, step * multiple
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
        self.baseline = (float(get_in["accel_input"]()[0]), float(get_in["steer_input"]()[0]),
                         bool(get_in["reverse_input"]()[0]) if get_in["reverse_input"] else False)
        self._limits = {s: codec.limits(STATUS, s) for s in ("Speed", "YawRate", "AccelActual")}

        self._status_counter = RollingCounter()
        self._status_times: dict[int, float] = {}  # status Counter -> sim time it reported
        self._answered: set[int] = set()  # status counters already answered (echo: repeats are not applied)
        self._awaiting: tuple[int, float] | None = None  # (counter, t_s) whose answer is due at t_s + h
        self._held: list[_Rx] = []
        self._active: _Rx | None = None
        self._t_fresh = t
        self._engaged = False
        self._lost = False
        self._fallback_since: float | None = None
        self._applied = (None, None, None, None)  # (mode, accel, steer, reverse) last written
        self._ages: list[float] = []
        self._last_t = t
        self.rx_commands = 0  # valid commands taken off the bus by the receive thread
        run_dir = Path(run_dir)
        self.stats = {"bus": cfg.bus.describe(), "dbc": str(codec.path), "vehicle": cfg.vehicle,
                      "sync": self.sync, "status_rate_hz": cfg.status_rate_hz, "status_every_steps": self.status_every,
                      "command_timeout_s": cfg.command_timeout_s, "on_timeout": cfg.on_timeout,
                      "timing_rule": _RULES[self.sync],
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
        self._csv_file = open(run_dir / APPLIED_CSV, "w", newline="", buffering=1)
        self._csv = csv.writer(self._csv_file)
        self._csv.writerow(["t", "event", "mode", "accel_cmd", "steer_cmd", "reverse", "counter", "status_echo",
                            "basis_t", "rx_time"])
        self._log({"t": t, "event": "open", "bus": cfg.bus.describe(), "sync": self.sync})
        if self.sync != "drain":
            self._thread = threading.Thread(target=self._receive, name="can-bridge", daemon=True)
            self._thread.start()
        self._write_inputs(t, "initial", Mode.MANUAL, *self.baseline, None)
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
                self._inbox.append(_Rx(value, msg.timestamp or time.time()))
                self.rx_commands += 1
                self._cond.notify_all()
        elif isinstance(value, CavHeartbeat):
            self.stats["heartbeats"] += 1
            self.stats["last_app_state"] = value.state.name
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
            self._classify(t)
            due = self._awaiting
            if (self.sync == "echo" and due is not None and due[1] + self.h <= t + _EPS
                    and due[0] not in self._answered and self._engaged and not self._lost):
                self.stats["sync_waits"] += 1
                w0 = time.monotonic()
                got = self._cond.wait_for(lambda: any(r.cmd.status_echo == due[0] for r in self._inbox),
                                          self.config.sync_timeout_s)
                self.stats["sync_wait_wall_s"] += time.monotonic() - w0
                if not got:
                    self._lost = True
                    self.stats["sync_timeouts"] += 1
                    self._log({"t": t, "event": "sync_timeout", "status_counter": due[0], "status_t": due[1],
                               "waited_s": self.config.sync_timeout_s})
                self._classify(t)
            if due is not None and due[1] + self.h <= t + _EPS:
                self._awaiting = None
        self._last_t = t
        eligible, held = [], []
        for r in self._held:
            (eligible if r.hold_until is None or r.hold_until <= t + _EPS else held).append(r)
        if eligible:
            self._held = held
            self.stats["commands_superseded"] += len(eligible) - 1
            self._active = eligible[-1]
            self._t_fresh = t
            self.stats["commands_applied"] += 1
            if self._active.basis_t is not None:
                self._ages.append(t - self._active.basis_t)
        self._apply(t)

    def _classify(self, t: float) -> None:
        """Move received commands into the held list with their basis time (called under the lock)."""
        while self._inbox:
            rx = self._inbox.popleft()
            self.stats["commands_received"] += 1
            self._engaged, self._lost = True, False
            echo = rx.cmd.status_echo
            rx.basis_t = self._status_times.get(echo)
            if rx.basis_t is None:
                self.stats["commands_unsynced"] += 1
            if self.sync == "echo" and rx.basis_t is not None:
                if echo in self._answered:
                    self.stats["commands_repeat_ignored"] += 1
                    continue
                self._answered.add(echo)
                rx.hold_until = rx.basis_t + self.h
            self._held.append(rx)

    def _apply(self, t: float) -> None:
        cfg, active = self.config, self._active
        if active is None:
            return
        if t - self._t_fresh >= cfg.command_timeout_s - _EPS:
            if self._fallback_since is None:
                self._fallback_since = t
                self.stats["timeouts"] += 1
                self._log({"t": t, "event": "command_timeout", "policy": cfg.on_timeout,
                           "last_command_t": self._t_fresh})
            accel, steer, reverse = active.cmd.accel, active.cmd.steer, active.cmd.reverse
            if active.cmd.mode == Mode.EMERGENCY_STOP:
                accel = cfg.estop_accel
            elif active.cmd.mode == Mode.MANUAL:
                accel, steer, reverse = self.baseline
            if cfg.on_timeout == "brake":
                accel = min(accel, cfg.timeout_accel)
            elif cfg.on_timeout == "zero_accel":
                accel = 0.0 if active.cmd.mode != Mode.EMERGENCY_STOP else accel
            elif cfg.on_timeout == "manual":
                accel, steer, reverse = self.baseline
            self._write_inputs(t, "fallback", Mode.FALLBACK, accel, steer, reverse, None)
            return
        if self._fallback_since is not None:
            self.stats["fallback_s"] += t - self._fallback_since
            self._fallback_since = None
        cmd = active.cmd
        event = "command" if self._t_fresh == t else None
        if cmd.mode == Mode.AUTO:
            self._write_inputs(t, event, Mode.AUTO, cmd.accel, cmd.steer, cmd.reverse, active)
        elif cmd.mode == Mode.EMERGENCY_STOP:
            self._write_inputs(t, event, Mode.EMERGENCY_STOP, cfg.estop_accel, cmd.steer, cmd.reverse, active)
        else:
            self._write_inputs(t, event, Mode.MANUAL, *self.baseline, active)

    def _write_inputs(self, t: float, event: str | None, mode: Mode, accel: float, steer: float, reverse: bool,
                      rx: _Rx | None) -> None:
        state = (mode, accel, steer, reverse)
        if state == self._applied and event != "command":
            return
        if state[1:] != self._applied[1:]:
            self._set["accel_input"]([float(accel)])
            self._set["steer_input"]([float(steer)])
            if self._set["reverse_input"] is not None:
                self._set["reverse_input"]([bool(reverse)])
        self._applied = state
        cmd = rx.cmd if rx is not None else None
        self._csv.writerow([repr(t), event or "mode", mode.name, repr(float(accel)), repr(float(steer)), int(reverse),
                            cmd.counter if cmd else "", cmd.status_echo if cmd else "",
                            repr(rx.basis_t) if rx is not None and rx.basis_t is not None else "",
                            repr(rx.rx_time) if rx is not None else ""])

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
        mode = self._applied[0] or Mode.MANUAL
        counter = self._status_counter.next()
        data = self.codec.encode_status(CavStatus(*values, mode=mode, reverse=bool(self._applied[3]),
                                                  counter=counter))
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
            self._status_times[counter] = t
            self._answered.discard(counter)
            self._awaiting = (counter, t)

    def close(self) -> dict[str, Any]:
        """Stop receiving, close the bus and logs; the run's CAN statistics (empty if never opened)."""
        if self.codec is None:
            return {}
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
        if self._fallback_since is not None:
            self.stats["fallback_s"] += self._last_t - self._fallback_since
            self._fallback_since = None
        for f in (self._events, self._csv_file):
            if f is not None:
                f.close()  # EventLog.close and file.close: both idempotent
        self._events = self._csv_file = None
        return self._snapshot()

    def _snapshot(self) -> dict[str, Any]:
        s = dict(self.stats)
        s["rejected"] = dict(self.checker.rejected)
        s["rejected_total"] = sum(self.checker.rejected.values())
        s["counter_gaps"] = self.checker.counter_gaps
        s["frames_ignored"] = dict(self._ignored)
        s["status_saturated"] = dict(self._saturated)
        if self._ages:
            s["actuation_age_s"] = {"min": min(self._ages), "max": max(self._ages),
                                    "mean": sum(self._ages) / len(self._ages), "n": len(self._ages)}
        return s

    def _log(self, event: dict[str, Any]) -> None:
        events = self._events
        if events is not None:  # EventLog ignores lines after close (the receive thread may still log)
            events(event)


__all__ = ["CanConfig", "CanBridge", "parse_can", "ON_TIMEOUT", "SYNC_MODES", "CAN_KEYS"]
