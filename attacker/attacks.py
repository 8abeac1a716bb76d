"""The attacks, chosen by name: each turns simulated time into frames for the air (pure: no bus, no clock).

    ATTACKS["ghost-unsigned"]  surrogate BSMs of a ghost vehicle, unsecured
    ATTACKS["ghost-untrusted"] the same, signed under a CA of the attacker's own
    ATTACKS["ghost-expired"]   the same, signed with a stolen, expired station certificate
    ATTACKS["replay"]          genuine frames heard on the air, sent again `delay_s` later from here
    ATTACKS["flood"]           random bytes at up to 2000 frames/s, at most `max_frames` in all

An attack is asked for the frames due in [t0, t1) (`frames`), and is told
what the attacker's station heard (`hear`, the frame's bytes and arrival
time). Times are the run's simulation time; frames at a fixed rate fall on
start_s + n / rate_hz, so a lockstep run sends the same frames at the same
instants every time. Every attack stops at `stop_s` and counts what it sent.

Parameters are dataclasses (field metadata: help and bounds): the config reader
(attacker.config) checks a table against them and `--list` prints them.
"""
from __future__ import annotations

import heapq
import itertools
import math
import random
import zlib
from dataclasses import dataclass, field
from typing import Any, ClassVar

from bridges.geo import GeoOrigin
from bridges.security import time64_us
from bridges.v2x import unix_time

from attacker.credentials import Wrap
from attacker.ghost import GhostPath, ghost_bsm, temporary_id

MAX_FLOOD_RATE_HZ = 2000.0  # a load test of the air must stay bounded: frames per second ...
MAX_FLOOD_FRAMES = 100_000  # ... and frames in all (per flood attack)
MAX_REPLAY_FRAMES = 100_000
MAX_GHOST_RATE_HZ = 100.0


def _p(default, help: str, low=None, high=None, low_open=False):
    return field(default=default, metadata={"help": help, "low": low, "high": high, "low_open": low_open})


@dataclass
class Window:
    start_s: float = _p(0.0, "first transmission (simulation s)", low=0.0)
    stop_s: float = _p(math.inf, "no transmission at or after this (simulation s; default: never stops)", low=0.0)


@dataclass
class GhostParams(Window):
    rate_hz: float = _p(10.0, "BSMs per second (J2945/1: 10)", low=0.0, high=MAX_GHOST_RATE_HZ, low_open=True)
    path: list = field(default_factory=lambda: [[-60.0, -1.75], [120.0, -1.75]], metadata={
        "help": "the ghost's route, [[x, y], ...] local metres (default: the eastbound lane from the west)",
        "points": True})
    speed_mps: float = _p(16.667, "its speed along the path from start_s (m/s)", low=0.0)
    length: float = _p(6.5, "body length (m)", low=0.0, high=40.0, low_open=True)
    width: float = _p(2.3, "body width (m)", low=0.0, high=10.0, low_open=True)
    emergency: bool = _p(True, "announce an emergency vehicle (siren and lightbar in use)")


@dataclass
class ReplayParams(Window):
    delay_s: float = _p(1.0, "how long after hearing a frame it is sent again (s); beyond the receivers' "
                             "window (0.5 s) it is too old, within it a duplicate", low=0.0, low_open=True)
    max_frames: int = _p(1000, "at most this many replays", low=1, high=MAX_REPLAY_FRAMES)


@dataclass
class FloodParams(Window):
    rate_hz: float = _p(200.0, "frames per second", low=0.0, high=MAX_FLOOD_RATE_HZ, low_open=True)
    max_frames: int = _p(1000, "at most this many frames in all", low=1, high=MAX_FLOOD_FRAMES)
    bytes: int = _p(200, "size of each frame (random bytes)", low=1, high=2000)


@dataclass
class Frame:
    """One transmission: its time, its bytes, which attack made it."""

    t: float
    payload: bytes
    attack: str


@dataclass
class Context:
    """What the attacks know of the run (the master's welcome) and the attacker's keys."""

    origin: GeoOrigin
    epoch_unix_s: float
    seed: int = 0
    envelopes: dict[str, Wrap] = field(default_factory=dict)  # "unsigned", "untrusted", "expired"


def slots(start: float, stop: float, rate_hz: float, t0: float, t1: float) -> list[tuple[int, float]]:
    """(n, start + n / rate_hz) for every n >= 0 with the time in [t0, t1) and before stop."""
    n = max(0, math.ceil((t0 - start) * rate_hz - 1e-6))
    out = []
    while True:
        t = round(start + n / rate_hz, 9)
        if t >= t1 - 1e-9 or t >= stop - 1e-9:
            return out
        if t >= t0 - 1e-9:
            out.append((n, t))
        n += 1


class Attack:
    kind: ClassVar[str]
    params_type: ClassVar[type]
    help: ClassVar[str]
    envelope: ClassVar[str | None] = None  # the Context envelope it needs

    def __init__(self, label: str, params, ctx: Context):
        self.label, self.p, self.ctx = label, params, ctx
        self.sent = 0

    def frames(self, t0: float, t1: float) -> list[Frame]:
        raise NotImplementedError

    def hear(self, payload: bytes, t_arrival: float) -> None:
        """What the station heard (only the replay listens)."""

    def summary(self) -> dict[str, Any]:
        return {"attack": self.label, "kind": self.kind, "sent": self.sent}


class GhostAttack(Attack):
    """Surrogate BSMs of a vehicle that is not there, in this attack's envelope."""

    params_type = GhostParams

    def __init__(self, label: str, params: GhostParams, ctx: Context):
        super().__init__(label, params, ctx)
        self.path = GhostPath([tuple(p) for p in params.path], params.speed_mps, params.start_s)
        self.tid = temporary_id(label, ctx.seed)
        self.wrap = ctx.envelopes[self.envelope]

    def frames(self, t0: float, t1: float) -> list[Frame]:
        p, out = self.p, []
        for n, t in slots(p.start_s, p.stop_s, p.rate_hz, t0, t1):
            payload = ghost_bsm(self.path.pose(t), t, self.ctx.epoch_unix_s, self.ctx.origin, self.tid, n,
                                p.length, p.width, p.emergency)
            out.append(Frame(t, self.wrap(payload, time64_us(unix_time(t, self.ctx.epoch_unix_s))), self.label))
        self.sent += len(out)
        return out

    def summary(self) -> dict[str, Any]:
        return {**super().summary(), "temporary_id": self.tid.hex()}


class GhostUnsigned(GhostAttack):
    kind, envelope = "ghost-unsigned", "unsigned"
    help = "surrogate BSMs of a ghost vehicle as unsecured data (no signature)"


class GhostUntrusted(GhostAttack):
    kind, envelope = "ghost-untrusted", "untrusted"
    help = "the ghost's BSMs signed by a certificate of the attacker's own CA (named like the scenario's)"


class GhostExpired(GhostAttack):
    kind, envelope = "ghost-expired", "expired"
    help = "the ghost's BSMs signed with a stolen, expired certificate of the scenario CA"


class Replay(Attack):
    """Genuine frames heard on the air, transmitted again delay_s after they arrived, from this station."""

    kind, params_type = "replay", ReplayParams
    help = "capture frames heard on v2x/rx/<station> and send them again delay_s later from here"

    def __init__(self, label: str, params: ReplayParams, ctx: Context):
        super().__init__(label, params, ctx)
        self._due: list[tuple[float, int, bytes]] = []
        self._order = itertools.count()
        self.captured = self.late = self.ignored = 0

    def hear(self, payload: bytes, t_arrival: float) -> None:
        p = self.p
        due = round(t_arrival + p.delay_s, 9)
        if t_arrival < p.start_s - 1e-9 or due >= p.stop_s - 1e-9 or self.captured >= p.max_frames:
            self.ignored += 1
            return
        self.captured += 1
        heapq.heappush(self._due, (due, next(self._order), bytes(payload)))

    def frames(self, t0: float, t1: float) -> list[Frame]:
        out = []
        while self._due and self._due[0][0] < t1 - 1e-9:
            due, _, payload = heapq.heappop(self._due)
            if due < t0 - 1e-9:  # heard after its replay time had passed: sent now, and counted
                self.late += 1
                due = t0
            out.append(Frame(due, payload, self.label))
        self.sent += len(out)
        return out

    def summary(self) -> dict[str, Any]:
        return {**super().summary(), "captured": self.captured, "late": self.late, "ignored": self.ignored,
                "pending_at_end": len(self._due)}


class Flood(Attack):
    """Random bytes at a bounded rate: what a receiver must refuse cheaply, frame after frame."""

    kind, params_type = "flood", FloodParams
    help = f"random frames at rate_hz (<= {MAX_FLOOD_RATE_HZ:g}/s), at most max_frames (<= {MAX_FLOOD_FRAMES})"

    def __init__(self, label: str, params: FloodParams, ctx: Context):
        super().__init__(label, params, ctx)
        self.rng = random.Random(zlib.crc32(f"{label}:{ctx.seed}".encode()))  # the same bytes every run

    def frames(self, t0: float, t1: float) -> list[Frame]:
        p, out = self.p, []
        for n, t in slots(p.start_s, p.stop_s, p.rate_hz, t0, t1):
            if n >= p.max_frames:
                break
            out.append(Frame(t, self.rng.randbytes(p.bytes), self.label))
        self.sent += len(out)
        return out


ATTACKS: dict[str, type[Attack]] = {cls.kind: cls for cls in (GhostUnsigned, GhostUntrusted, GhostExpired,
                                                               Replay, Flood)}


def describe() -> str:
    """Every attack with its parameters and defaults (for --list and --help)."""
    from dataclasses import fields

    lines = []
    for name, cls in ATTACKS.items():
        lines.append(f"{name}: {cls.help}")
        for f in fields(cls.params_type):
            default = f.default_factory() if callable(f.default_factory) else f.default
            lines.append(f"    {f.name} = {default!r}: {f.metadata.get('help', '')}")
    return "\n".join(lines)

