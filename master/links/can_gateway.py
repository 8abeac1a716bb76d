"""The drive-by-wire gateway's decisions: which AV_Command drives the vehicle at each communication point.

Why a module of its own: what the vehicle does is decided by a handful of timing
rules, and those rules are what makes a CAN run reproducible. They are kept
here, in simulated time only, apart from everything that makes them hard to
test: the python-can bus, the receive thread, the wall-clock wait, the FMU and
the files. ``master.links.can_bridge.CanBridge`` is the thin adapter that feeds this
core what happened on the bus and writes what it answers (as ``Air`` in
``master.links.radio_bridge`` is the core of ``RadioBridge``).

Timing rule ("t + one step"). CAN frames carry no simulation time, so the
gateway ties each command to the status frame it answers: every AV_Status has
an 8-bit Counter, every AV_Command echoes the Counter of the status it was
computed from (``StatusEcho``). A status sent at simulation time t_s (after the
step that ends at t_s) is answered by a command that is applied at the
communication point t_s + h (h: the vehicle's communication step), never
earlier, whatever the wall-clock speed of the app:

* ``sync = "echo"`` (lockstep default): before stepping from t_s + h, the master
  waits (up to ``sync_timeout_s`` wall seconds; the bridge does the waiting,
  :meth:`Gateway.awaited` says for what) until the answer to the status of t_s
  has been received; an answer that arrives before the master has even finished
  the step from t_s is held back until t_s + h. The master and the app therefore
  overlap by one step (the master steps [t_s, t_s+h) while the app computes), and
  the app's compute time counts as exactly one step of simulated actuation
  latency: runs are bit-for-bit reproducible. Contract for the app: one
  AV_Command per AV_Status received (further commands echoing the same status are
  counted as repeats and not applied). A silent app loses its turn after
  ``sync_timeout_s`` (:meth:`Gateway.lost_turn`); the master then runs free until
  a command arrives again, and the simulated ``command_timeout_s`` policy takes
  over.
* ``sync = "drain"`` (with the time protocol, [participants]): no receive thread;
  at each communication point the master reads every frame already on the bus
  and applies the latest command there. Deterministic when something else orders
  the app and the master: an app that sends its AV_Command before it acknowledges
  the tick, with a master that waits for the acknowledgements before this point,
  has its command applied at this point (on one host: the datagram is in the
  socket before the acknowledgement leaves; across hosts the two paths may race).
* ``sync = "free"`` (echo becomes free in realtime mode, for HIL): the latest valid
  command received before a communication point is applied there, as a gateway on
  a real bus would. The echo still gives each command's basis time, so the run
  records its actuation age t_applied - t_status.

Between commands the vehicle keeps the last one; after ``command_timeout_s`` of
simulated time without a new one the ``on_timeout`` policy applies (Mode
FALLBACK) until a command comes again. EMERGENCY_STOP brakes with
``estop_accel`` whatever acceleration it asks for; MANUAL gives the vehicle back
its own inputs (the baseline read before the first step).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

from bridges.can.codec import AppState, CavCommand, Mode

__all__ = ["Gateway", "Received", "Actuation", "StatusFrame", "TIMING_RULES"]

_EPS = 1e-9  # times within this are the same communication point
TIMING_RULES = {"echo": "a command answering the AV_Status of time t is applied at t + h",
                "drain": "every command on the bus when the master reaches communication point t is applied at t "
                         "(read in the master thread, so none is missed by a thread race)",
                "free": "the latest valid command received before a communication point is applied there"}
_POLICIES = ("brake", "zero_accel", "hold", "manual")


class StatusFrame(NamedTuple):
    """An AV_Status as sent: its Counter and the simulation time it reported."""

    counter: int
    t: float


@dataclass
class Received:
    """A valid command as the gateway took it: its bus timestamp and the sim time of the status it answers."""

    cmd: CavCommand
    rx_time: float
    basis_t: float | None = None  # sim time of the AV_Status it echoes (None: unknown echo)
    hold_until: float | None = None  # echo: not applied before basis_t + h


@dataclass(frozen=True)
class Actuation:
    """What to write to the vehicle at communication point t, and why (one row of can-applied.csv)."""

    t: float
    event: str  # "initial", "command" (a command applied now), "fallback" (the timeout policy), "mode"
    mode: Mode
    accel: float
    steer: float
    reverse: bool
    source: Received | None  # the command behind it (None: the initial inputs or the fallback)
    inputs_changed: bool  # accel, steer or reverse differ from what was last written

    @property
    def command(self) -> CavCommand | None:
        return self.source.cmd if self.source is not None else None

    @property
    def basis_t(self) -> float | None:
        return self.source.basis_t if self.source is not None else None


class Gateway:
    """Decides, in simulated time, which received command drives the vehicle at each communication point.

    Feed it what happened, in order: :meth:`status_sent` after each AV_Status,
    :meth:`received` for each valid AV_Command (in bus order), :meth:`heartbeat`;
    at each communication point t ask :meth:`awaited` (echo: the status whose
    answer must be in before stepping from t), then call :meth:`reach`, which
    answers the :class:`Actuation` to write (None: the vehicle's inputs stay as
    they are). Not thread-safe: the bridge calls it under its lock.
    """

    def __init__(self, sync: str, h: float, t0: float, baseline: tuple[float, float, bool], *,
                 command_timeout_s: float, on_timeout: str, timeout_accel: float, estop_accel: float,
                 log: Callable[[dict[str, Any]], None] | None = None):
        if sync not in TIMING_RULES:
            raise ValueError(f"sync must be one of {', '.join(TIMING_RULES)}, got {sync!r}")
        if on_timeout not in _POLICIES:
            raise ValueError(f"on_timeout must be one of {', '.join(_POLICIES)}, got {on_timeout!r}")
        self.sync, self.h = sync, h
        self.baseline = baseline  # (accel, steer, reverse): the vehicle's own inputs, for MANUAL
        self.command_timeout_s, self.on_timeout = command_timeout_s, on_timeout
        self.timeout_accel, self.estop_accel = timeout_accel, estop_accel
        self.log = log or (lambda event: None)
        self._t0 = t0
        self._status_times: dict[int, float] = {}  # status Counter -> sim time it reported
        self._answered: set[int] = set()  # status counters already answered (echo: repeats are not applied)
        self._awaiting: StatusFrame | None = None  # the status whose answer is due at its t + h
        self._held: list[Received] = []  # received, not yet applied
        self._active: Received | None = None  # the command driving the vehicle
        self._t_fresh = t0  # when a command was last applied
        self._engaged = False  # a command has been received at all
        self._lost = False  # echo: the app missed its turn; no waiting until it answers again
        self._fallback_since: float | None = None
        self._written: tuple | None = None  # (mode, accel, steer, reverse) last written
        self._last_t = t0
        self._ages: list[float] = []
        self._counts = {"commands_received": 0, "commands_applied": 0, "commands_superseded": 0,
                        "commands_repeat_ignored": 0, "commands_unsynced": 0, "heartbeats": 0,
                        "last_app_state": None, "timeouts": 0}
        self._fallback_s = 0.0

    # -- what happened ------------------------------------------------------------------------
    def start(self) -> Actuation:
        """The inputs before the first step: the vehicle's own (MANUAL), written once as the "initial" row."""
        return self._actuate(self._t0, "initial", Mode.MANUAL, *self.baseline, None)

    def status_sent(self, counter: int, t: float) -> None:
        """An AV_Status with `counter` reported the vehicle at sim time t; its answer is due at t + h."""
        self._status_times[counter] = t
        self._answered.discard(counter)
        self._awaiting = StatusFrame(counter, t)

    def received(self, cmd: CavCommand, rx_time: float) -> None:
        """A valid AV_Command taken off the bus (rx_time: its bus timestamp, wall clock)."""
        rx = Received(cmd, rx_time)
        self._counts["commands_received"] += 1
        self._engaged, self._lost = True, False
        echo = cmd.status_echo
        rx.basis_t = self._status_times.get(echo)
        if rx.basis_t is None:
            self._counts["commands_unsynced"] += 1
        if self.sync == "echo" and rx.basis_t is not None:
            if echo in self._answered:
                self._counts["commands_repeat_ignored"] += 1
                return
            self._answered.add(echo)
            rx.hold_until = rx.basis_t + self.h
        self._held.append(rx)

    def heartbeat(self, state: AppState) -> None:
        self._counts["heartbeats"] += 1
        self._counts["last_app_state"] = state.name

    def awaited(self, t: float) -> StatusFrame | None:
        """sync = echo: the status whose answer must be received before stepping from t (None: go on)."""
        due = self._awaiting
        if (self.sync == "echo" and due is not None and due.t + self.h <= t + _EPS
                and due.counter not in self._answered and self._engaged and not self._lost):
            return due
        return None

    def lost_turn(self) -> None:
        """The awaited answer did not come in time: stop waiting for the app until it sends again."""
        self._lost = True

    # -- what to do -------------------------------------------------------------------------
    def reach(self, t: float) -> Actuation | None:
        """Communication point t: apply the latest command due here, or the timeout policy."""
        due = self._awaiting
        if due is not None and due.t + self.h <= t + _EPS:
            self._awaiting = None
        self._last_t = t
        eligible, held = [], []
        for rx in self._held:
            (eligible if rx.hold_until is None or rx.hold_until <= t + _EPS else held).append(rx)
        if eligible:
            self._held = held
            self._counts["commands_superseded"] += len(eligible) - 1
            self._active = eligible[-1]
            self._t_fresh = t
            self._counts["commands_applied"] += 1
            if self._active.basis_t is not None:
                self._ages.append(t - self._active.basis_t)
        return self._decide(t)

    def _decide(self, t: float) -> Actuation | None:
        active = self._active
        if active is None:
            return None
        cmd = active.cmd
        if t - self._t_fresh >= self.command_timeout_s - _EPS:
            if self._fallback_since is None:
                self._fallback_since = t
                self._counts["timeouts"] += 1
                self.log({"t": t, "event": "command_timeout", "policy": self.on_timeout,
                          "last_command_t": self._t_fresh})
            return self._actuate(t, "fallback", Mode.FALLBACK, *self._fallback(cmd), None)
        if self._fallback_since is not None:
            self._fallback_s += t - self._fallback_since
            self._fallback_since = None
        event = "command" if self._t_fresh == t else None
        if cmd.mode == Mode.AUTO:
            return self._actuate(t, event, Mode.AUTO, cmd.accel, cmd.steer, cmd.reverse, active)
        if cmd.mode == Mode.EMERGENCY_STOP:
            return self._actuate(t, event, Mode.EMERGENCY_STOP, self.estop_accel, cmd.steer, cmd.reverse, active)
        return self._actuate(t, event, Mode.MANUAL, *self.baseline, active)

    def _fallback(self, cmd: CavCommand) -> tuple[float, float, bool]:
        """The on_timeout policy's inputs, starting from what the last command was doing."""
        accel, steer, reverse = cmd.accel, cmd.steer, cmd.reverse
        if cmd.mode == Mode.EMERGENCY_STOP:
            accel = self.estop_accel
        elif cmd.mode == Mode.MANUAL:
            accel, steer, reverse = self.baseline
        if self.on_timeout == "brake":
            accel = min(accel, self.timeout_accel)
        elif self.on_timeout == "zero_accel":
            accel = 0.0 if cmd.mode != Mode.EMERGENCY_STOP else accel
        elif self.on_timeout == "manual":
            accel, steer, reverse = self.baseline
        return accel, steer, reverse

    def _actuate(self, t: float, event: str | None, mode: Mode, accel: float, steer: float, reverse: bool,
                 source: Received | None) -> Actuation | None:
        """An Actuation when something changed or a command was applied now; None otherwise."""
        state = (mode, accel, steer, reverse)
        if state == self._written and event != "command":
            return None
        changed = self._written is None or state[1:] != self._written[1:]
        self._written = state
        return Actuation(t, event or "mode", mode, accel, steer, reverse, source, changed)

    # -- what it says -------------------------------------------------------------------------
    def reported(self) -> tuple[Mode, bool]:
        """What AV_Status reports: the mode and reverse last written (MANUAL before anything was)."""
        if self._written is None:
            return Mode.MANUAL, False
        return self._written[0], bool(self._written[3])

    def stats(self) -> dict[str, Any]:
        """Commands received/applied/superseded/repeat_ignored/unsynced, heartbeats, timeouts, fallback_s
        (an open fallback counts up to the last communication point reached), actuation ages."""
        s: dict[str, Any] = dict(self._counts)
        s["fallback_s"] = self._fallback_s
        if self._fallback_since is not None:
            s["fallback_s"] += self._last_t - self._fallback_since
        s["actuation_age_s"] = None
        if self._ages:
            s["actuation_age_s"] = {"min": min(self._ages), "max": max(self._ages),
                                    "mean": sum(self._ages) / len(self._ages), "n": len(self._ages)}
        return s
