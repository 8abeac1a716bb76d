"""One protocol for everything that acts around a step of the master's loop.

The stepping loop (master.run.cosim) knows nothing of serial ports, CAN buses,
apps, the world or the radio: each is a *hook* with the same four methods, and
the loop calls them in a fixed order around the FMUs' step (the order defines
the results; docs/architecture.md, "The stepping loop"):

    open(ctx)               once, before the first step; returns its metadata section (or None)
    before_step(k, t)       manipulators: act on the FMUs' inputs before the step from t = t0 + k*h
    after_step(k, t_next)   observers: see the state at t_next = t0 + (k + 1)*h
    close(outcome)          once, whatever happened, if open was called; returns its final section

A hook implements what it needs (the base class's methods do nothing). The
run context carries what hooks share and the master owns: the FMU members, the
run folder, the time settings, the bus, the world and the event log. A hook may
end the run early with `ctx.request_stop(reason)`; the loop finishes the step
it is in, then every hook closes with the same `Outcome`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable


@dataclass
class Member:
    """An FMU instance in the loop with its step multiple and pre-bound transfers."""

    fmu: Any  # master.fmi.runtime.FmuInstance
    multiple: int
    inputs: list[tuple[Callable, list[int]]] = field(default_factory=list)  # (setter, source slots)
    outputs: list[tuple[Callable, int, int]] = field(default_factory=list)  # (getter, first slot, end slot)


@dataclass
class Outcome:
    """How the run ended, as every hook's close sees it."""

    status: str  # "completed", "stopped" (a hook or stop condition asked), "failed", "interrupted"
    error: str | None = None
    steps_done: int = 0
    t_end: float = 0.0  # simulation time reached
    stop_reason: str | None = None


class RunContext:
    """What the hooks of one run share. Owned by the master; hooks read it and may add the world."""

    def __init__(self, scenario, run_dir: Path, members: dict[str, Member], quiet: bool = True):
        t = scenario.time
        self.scenario = scenario
        self.run_dir = Path(run_dir)
        self.members = members
        self.quiet = quiet
        self.t0, self.h, self.n_steps = t.start, t.step, t.n_steps
        self.mode, self.rtf = t.mode, t.rtf
        self.bus = None  # the run's bus (bridges.transport), opened by the master when the scenario has [bridge]
        self.prefix: str | None = None  # its key prefix
        self.world = None  # master.world.world.World, once the world hook has opened it
        self.serial_urls: dict[str, str] = {}  # [serial.NAME] -> its pyserial URL, once the ports are open
        self.stop_reason: str | None = None
        self.clock = None  # realtime with participants: () -> the run clock's time now, or None before it runs
        self.pacer = None  # realtime: master.run.pacing.Pacer, the steps' wall-clock schedule
        self._events = None

    @property
    def fmus(self) -> dict[str, Any]:
        return {name: m.fmu for name, m in self.members.items()}

    @property
    def events(self):
        """The run's `events.jsonl` (master.events.EventLog), created on first use."""
        if self._events is None:
            from master.events import EventLog

            self._events = EventLog(self.run_dir)
        return self._events

    def close_events(self) -> dict[str, int] | None:
        return self._events.close() if self._events is not None else None

    def stamp_time(self, t: float) -> float:
        """The time to stamp on what the master hands the apps (sensor samples, air arrivals, applied
        commands) at step time t.

        In lockstep that is t. In realtime the apps stamp their own work with the run clock (the master's
        published sim/wall mapping), so the master stamps on the same clock: every stage of the latency
        chain is then wall-clock time on one clock, even while the loop lags behind its schedule (stamping
        the step's time mixed two clocks, and a realtime run matched 7 of 139 records end to end)."""
        if self.clock is not None:
            now = self.clock()
            if now is not None:
                return now
        return t

    def request_stop(self, reason: str) -> None:
        """End the run after the current step (the first reason given wins)."""
        if self.stop_reason is None:
            self.stop_reason = reason


class Hook:
    """Base of the loop's hooks: every method is optional. `name` is the hook's metadata section."""

    name: str = ""
    opens_after: tuple[str, ...] = ()  # hooks (by name) that must open before this one

    def open(self, ctx: RunContext) -> dict[str, Any] | None:
        return None

    def before_step(self, k: int, t: float) -> None:
        """Before the step from t."""

    def after_step(self, k: int, t_next: float) -> None:
        """After the step, at t_next."""

    def close(self, outcome: Outcome) -> dict[str, Any] | None:
        return None


def overrides(hook: Any, method: str) -> bool:
    """Does `hook` do anything in `method`? (The loop skips the base class's no-ops.)"""
    own = getattr(hook, method, None)
    if own is None:
        return False
    base = getattr(Hook, method)
    return getattr(own, "__func__", own) is not base


def open_order(hooks: Iterable[Hook]) -> list[Hook]:
    """The step order, except that a hook naming others in `opens_after` opens after them."""
    pending = list(hooks)
    names = {h.name for h in pending}
    done: list[Hook] = []
    opened: set[str] = set()
    while pending:
        for i, hook in enumerate(pending):
            if all(n in opened or n not in names for n in hook.opens_after):
                done.append(pending.pop(i))
                opened.add(hook.name)
                break
        else:  # a cycle: a programming error in the hooks' declarations
            raise ValueError(f"hooks wait for each other to open: {[h.name for h in pending]}")
    return done
