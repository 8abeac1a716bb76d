"""The V2X air: frames the apps transmit reach each receiver through the channel model, or not.

Apps publish encoded frames (J2735 in the security envelope) on
`v2x/tx/<station>`. For each other station within `max_range_m` the air asks a
channel model (the V2XChannel FMU's model code, one instance per transmitter,
so each has its own access schedule) whether the frame is decoded and how long
it took, with positions from the world (vehicles follow their FMU) and walls
and metres inside buildings from the world's line-of-sight query. A delivered
frame is published on `v2x/rx/<receiver>` at its simulated arrival time; a
dropped one is only logged. Every frame is logged as sent, and per receiver as
dropped (with the reason) or delivered (with its times).

Each frame's events also say which world vehicle it describes (`subject`, the
FMU instance; None when the air cannot tell) and the time of the camera frame
its information comes from (`frame_t`, the FRAME stamp in seconds, or None):
the hook unwraps the envelope without verifying it, decodes a BSM's position
and takes the nearest vehicle within a gate (master.links.v2x_subject). The metrics'
age of information per "receiver<-subject" is built on these (master.run.metrics).

`mode = "bypass"` lets apps hear each other directly and the air only logs
what was sent. `mode = "rsu"` puts real radios in the loop: the frames of one
station go to a real roadside unit as Immediate Forward records and what an
on-board unit forwards back reaches another station, with the real delay;
every other link stays on the channel model (master.links.rsu_link has the keys).

    [v2x]
    mode = "channel"            # or "bypass", or "rsu" (real radios: master.links.rsu_link)
    max_range_m = 1000.0
    j2735_edition = "2016"      # optional, or "2020": started apps get it as V2I_J2735_EDITION
                                # (bridges/j2735/editions.py); unset, each app's default (2020)
    [v2x.channel]               # V2XChannel parameters (fmus/channel/model.py ChannelParams)
    technology = "dsrc"
    [v2x.stations.rsu1]
    position = [6.5, 6.5, 6.0]  # antenna base (m); the channel adds its antenna height
    [v2x.stations.cav]
    vehicle = "cav"             # follows this VehicleDynamics instance
"""
from __future__ import annotations

import heapq
import itertools
import math
import random
import threading
from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable

from bridges.j2735.editions import EDITIONS
from bridges.v2x import AIR_ARRIVAL, FRAME, TX_KEY, rx_key, stamp_ns, stamp_s, tx_key
from master.links import rsu_link
from master.links.rsu_link import Delivery  # the air and the real link deliver alike
from master.hooks import Hook, Outcome, RunContext
from master.scenario.tables import Table, did_you_mean, is_number

MODES = ("channel", "bypass", "rsu")
_KEYS = ("mode", "max_range_m", "channel", "stations", "j2735_edition") + rsu_link.KEYS
_STATION_KEYS = ("position", "vehicle")


@dataclass
class Station:
    name: str
    position: tuple[float, float, float] | None = None  # fixed stations
    vehicle: str | None = None  # or one that follows a vehicle instance


@dataclass
class V2xSpec:
    mode: str = "channel"
    max_range_m: float = 1000.0
    channel: dict[str, Any] = field(default_factory=dict)  # ChannelParams overrides
    stations: dict[str, Station] = field(default_factory=dict)
    rsu: rsu_link.RsuLinkSpec | None = None  # mode = "rsu": the link through the real devices
    j2735_edition: str | None = None  # the J2735 edition on the air, when set: started apps get V2I_J2735_EDITION

    def resolved(self) -> dict[str, Any]:
        return {"mode": self.mode, "max_range_m": self.max_range_m, "channel": dict(self.channel),
                **({"j2735_edition": self.j2735_edition} if self.j2735_edition else {}),
                **(self.rsu.resolved() if self.rsu is not None else {}),
                "stations": {n: {k: v for k, v in (("position", list(s.position) if s.position else None),
                                                    ("vehicle", s.vehicle)) if v is not None}
                             for n, s in self.stations.items()}}


def read_section(value: Any, context) -> V2xSpec | None:
    """The `[v2x]` section's reader (master.scenario.sections; it also checks that the file has a [bridge])."""
    return parse_v2x(value, context.instances, context.problem)


def parse_v2x(table: Any, instances: dict, problem: Callable[[str, str], None]) -> V2xSpec | None:
    """Validate `[v2x]`; each problem goes to `problem(key, message)`."""
    from fmus.channel.model import ChannelParams

    t = Table(table, "v2x", problem)
    if not t.ok:
        return None
    t.unknown_keys(_KEYS)
    spec = V2xSpec()
    spec.mode = t.choice("mode", MODES, spec.mode)
    if "j2735_edition" in t:  # unset: each app's own default (2020, or its licensed files' edition)
        spec.j2735_edition = t.choice("j2735_edition", tuple(EDITIONS), None)
    spec.max_range_m = t.number("max_range_m", spec.max_range_m, low=0, low_open=True, expected="a number > 0")
    channel = t.sub("channel", "a table of V2XChannel parameters")
    if channel.ok:
        names = {f.name: f for f in fields(ChannelParams)}
        for key in channel.raw:
            if key not in names:
                hint = did_you_mean(key, names)
                channel.problem(key, "unknown channel parameter (see fmus/channel/model.py ChannelParams)"
                                + (f"; {hint}" if hint else ""))
        try:
            replace(ChannelParams(), **{k: v for k, v in channel.raw.items() if k in names}).validate()
            spec.channel = dict(channel.raw)
        except (ValueError, TypeError) as exc:
            channel.problem(None, str(exc))
    stations = t.sub("stations", "at least one [v2x.stations.NAME] table")
    if stations.ok and not stations.raw:
        stations.problem(None, "expected at least one [v2x.stations.NAME] table")
    for name in stations.raw:
        s = stations.sub(name)
        if not s.ok:
            continue
        s.unknown_keys(_STATION_KEYS)
        if ("position" in s) == ("vehicle" in s):
            s.problem(None, "give exactly one of position = [x, y, z] or vehicle = INSTANCE")
            continue
        if "position" in s:
            pos = s.get("position")
            if not isinstance(pos, list) or len(pos) != 3 or not all(is_number(v) for v in pos):
                s.problem("position", f"expected [x, y, z] in metres, got {pos!r}")
                continue
            spec.stations[name] = Station(name, position=tuple(float(v) for v in pos))
        else:
            vehicle = s.get("vehicle")
            inst = instances.get(vehicle) if isinstance(vehicle, str) else None
            if inst is None:
                s.problem("vehicle", f"no FMU instance {vehicle!r} in [fmus] (instances: {', '.join(instances)})")
                continue
            outputs = {v.name for v in inst.model_description.modelVariables if v.causality == "output"}
            if not {"x", "y"} <= outputs:
                s.problem("vehicle", f"instance {vehicle!r} has no x, y outputs to place the station")
                continue
            spec.stations[name] = Station(name, vehicle=vehicle)
    if spec.mode == "rsu":
        spec.rsu = rsu_link.parse_link(t, list(stations.raw), spec.channel.get("technology", "dsrc"))
    else:
        for key in rsu_link.KEYS:
            if key in t:
                t.problem(key, f"only with mode = \"rsu\" (real radios in the loop); mode is {spec.mode!r}")
    return spec if t.ok else None


@dataclass(order=True)
class _Pending:
    arrival: float
    order: int
    receiver: str = field(compare=False)
    sender: str = field(compare=False)
    seq: int = field(compare=False)
    t_tx: float = field(compare=False)
    payload: bytes = field(compare=False)
    stamps: dict = field(compare=False)
    about: dict = field(compare=False, default_factory=dict)




def _with(event: dict, about: dict | None) -> dict:
    """An event with a frame's extra fields added after its own (which they never replace)."""
    if about:
        for key, value in about.items():
            event.setdefault(key, value)
    return event


class Air:
    """Channel decisions and the queue of frames in flight (no transport: testable alone).

    `position(station, t)` gives a station's antenna base (x, y, z);
    `obstruction(p, q)` gives (blocked, walls, metres inside) for the straight path.
    """

    def __init__(self, spec: V2xSpec, position: Callable[[str, float], tuple[float, float, float]],
                 obstruction: Callable[[Any, Any], tuple[bool, int, float]] | None = None,
                 log: Callable[[dict], None] | None = None):
        from fmus.channel.model import ChannelModel, ChannelParams

        self.spec, self.position = spec, position
        # links carried by something else (mode = "rsu": real devices), skipped here
        self.elsewhere = {(spec.rsu.rsu_station, spec.rsu.obu_station)} if spec.rsu is not None else set()
        self.obstruction = obstruction or (lambda p, q: (False, 0, 0.0))
        self.log = log or (lambda event: None)
        base = replace(ChannelParams(), **spec.channel)
        names = sorted(spec.stations)
        self.ids = {n: i for i, n in enumerate(names)}
        # one radio per transmitter: its own seed, so access schedules and fading differ between stations
        self.models = {n: ChannelModel(replace(base, seed=base.seed + 7919 * i)).prepare() for n, i in self.ids.items()}
        self._heap: list[_Pending] = []
        self._order = itertools.count()
        self.counts = {"sent": 0, "delivered": 0, "dropped": 0, "out_of_range": 0, "unknown_sender": 0}
        # scenario events ("link"): (tx, rx, loss, extra delay) by handle; "*" matches any station
        self.impairments: dict[int, tuple[str, str, float, float]] = {}
        self._impair_rng = random.Random(base.seed ^ 0x5EED)  # decisions repeat from run to run
        self._handles = itertools.count(1)

    def impair(self, tx: str, rx: str, loss: float, delay_s: float) -> int:
        """From now on, frames on tx -> rx that the channel delivers are dropped with probability `loss`
        (reason "event") or arrive `delay_s` later; returns the handle that `restore` takes."""
        handle = next(self._handles)
        self.impairments[handle] = (tx, rx, float(loss), float(delay_s))
        return handle

    def restore(self, handle: int) -> None:
        self.impairments.pop(handle, None)

    def _impaired(self, sender: str, receiver: str) -> tuple[bool, float]:
        """(dropped by an event, extra delay) for one delivery on sender -> receiver."""
        delay = 0.0
        for tx, rx, loss, extra in self.impairments.values():
            if tx in ("*", sender) and rx in ("*", receiver):
                if loss > 0 and self._impair_rng.random() < loss:
                    return True, 0.0
                delay += extra
        return False, delay

    def transmit(self, sender: str, seq: int, t_tx: float, payload: bytes, stamps: dict | None = None,
                 about: dict | None = None) -> None:
        """A frame on the air at t_tx: decide its fate at every other station now.

        `about`: extra fields for every event of this frame (sent, dropped, scheduled, delivered), e.g. the
        vehicle it describes (`subject`) and its camera-frame time (`frame_t`); they never replace the
        event's own fields.
        """
        if sender not in self.spec.stations:
            self.counts["unknown_sender"] += 1
            self.log({"event": "v2x_rejected", "t": t_tx, "from": sender, "seq": seq,
                      "reason": f"unknown station {sender!r} (stations: {', '.join(self.spec.stations)})"})
            return
        about = dict(about) if about else {}
        self.counts["sent"] += 1
        self.log(_with({"event": "v2x_sent", "t": t_tx, "from": sender, "seq": seq, "bytes": len(payload)}, about))
        if self.spec.mode == "bypass":
            return
        tx = self.position(sender, t_tx)
        model = self.models[sender]
        h_tx, h_rx = model.p.tx_antenna_height_m, model.p.rx_antenna_height_m
        for receiver in self.spec.stations:
            if receiver == sender or (sender, receiver) in self.elsewhere:
                continue
            rx = self.position(receiver, t_tx)
            d = math.dist(tx, rx)
            if d > self.spec.max_range_m:
                self.counts["out_of_range"] += 1
                self.log(_with({"event": "v2x_dropped", "t": t_tx, "from": sender, "to": receiver, "seq": seq,
                                "reason": "out_of_range", "distance_m": round(d, 2)}, about))
                continue
            _, walls, inside = self.obstruction((tx[0], tx[1], tx[2] + h_tx), (rx[0], rx[1], rx[2] + h_rx))
            link = model.evaluate_one(tx, rx, walls, inside, packet_bytes=max(len(payload), 1), seq=seq,
                                      tx_id=self.ids[sender], rx_id=self.ids[receiver])
            facts = {"distance_m": round(link["distance_m"], 2), "walls": int(walls),
                     "rx_power_dbm": round(link["rx_power_dbm"], 2), "snr_db": round(link["snr_db"], 2)}
            if not link["delivered"]:
                self.counts["dropped"] += 1
                self.log(_with({"event": "v2x_dropped", "t": t_tx, "from": sender, "to": receiver, "seq": seq,
                                "reason": "channel", "per": round(link["per"], 4), **facts}, about))
                continue
            arrival = t_tx + float(link["latency_s"])
            if self.impairments:
                dropped, extra = self._impaired(sender, receiver)
                if dropped:
                    self.counts["dropped"] += 1
                    self.log(_with({"event": "v2x_dropped", "t": t_tx, "from": sender, "to": receiver, "seq": seq,
                                    "reason": "event", **facts}, about))
                    continue
                arrival += extra
            heapq.heappush(self._heap, _Pending(arrival, next(self._order), receiver, sender, seq, t_tx, payload,
                                                dict(stamps or {}), about))
            self.log(_with({"event": "v2x_scheduled", "t": t_tx, "from": sender, "to": receiver, "seq": seq,
                            "arrival": arrival, **facts}, about))

    def due(self, t: float) -> list[Delivery]:
        """Frames whose arrival time is <= t, in arrival order."""
        out = []
        while self._heap and self._heap[0].arrival <= t + 1e-12:
            p = heapq.heappop(self._heap)
            self.counts["delivered"] += 1
            self.log(_with({"event": "v2x_delivered", "t": p.arrival, "from": p.sender, "to": p.receiver,
                            "seq": p.seq, "t_tx": p.t_tx, "latency_s": p.arrival - p.t_tx}, p.about))
            out.append(Delivery(p.receiver, p.sender, p.seq, p.t_tx, p.arrival, p.payload, p.stamps, p.about))
        return out

    @property
    def in_flight(self) -> int:
        return len(self._heap)


@dataclass
class _Injected:
    """A frame a scenario event puts on the air (the fields of a bus message the hook reads)."""

    key: str
    t_sim: float
    sender: str
    seq: int
    payload: bytes
    stamps: dict = field(default_factory=dict)


class RadioBridge(Hook):
    """The air in the master's loop: takes frames from `v2x/tx/*` on the bus, delivers to `v2x/rx/<name>`.

    Frames received from the bus are buffered by a subscriber thread and put on
    the air in the master's thread at the next step, at their own t_sim (a
    frame stamped earlier than the step already done is put on the air at once
    and counted as late). Hooks: open / after_step / close, like the serial and
    world bridges. The bus and the event log are the run's (`RunContext`).

    Frames are tied to the world vehicle they describe (`subject`, `frame_t` in
    the air's events; master.links.v2x_subject), once per frame put on the air.

    With `mode = "rsu"` the frames of the RSU station also go to the real RSU
    and the OBU's forwards come back through `link` (master.links.rsu_link), whose
    sockets are opened here and closed with the hook.
    """

    name = "v2x"

    def __init__(self, spec: V2xSpec):
        self.spec = spec
        self.bus = None
        self.log: Callable[[dict], None] = lambda e: None
        self.air: Air | None = None
        self._inbox: list[Any] = []
        self._lock = threading.Lock()
        self._sub = None
        self._fmus: dict[str, Any] = {}
        self._getters: dict[str, Any] = {}
        self._world = None
        self._t_done = -math.inf
        self._waiting: list[tuple] = []  # (t_sim, sender, seq, order, message) not yet on the air
        self._order = itertools.count()
        self.late = 0
        self.subjects = None  # master.links.v2x_subject.SubjectFinder, once open
        self.link: rsu_link.RsuLink | None = None  # mode = "rsu", once open
        self._sockets: rsu_link.LinkSockets | None = None
        self._stamp_time: Callable[[float], float] = lambda t: t
        self._injected = 0

    def open(self, ctx: RunContext) -> dict[str, Any]:
        self.bus, self.log = ctx.bus, ctx.events
        self._stamp_time = ctx.stamp_time  # realtime: arrivals stamped on the run clock, as the apps stamp
        fmus, t, world = ctx.fmus, ctx.t0, ctx.world
        self._world = world
        for st in self.spec.stations.values():
            if st.vehicle is not None:
                fmu = fmus[st.vehicle]
                self._getters[st.name] = fmu.accessor(
                    fmu.access_key("x"), [fmu.variables[n].valueReference for n in ("x", "y")], setter=False)
        obstruction = world.line_of_sight if world is not None else None
        self.air = Air(self.spec, self._position, obstruction, self.log)
        self.subjects = _subject_finder(ctx)
        if self.spec.rsu is not None:
            self.link = self._open_link(ctx)
        self._sub = self.bus.subscribe(TX_KEY.format("*"), callback=self._on_tx)
        self._t_done = t
        return {"mode": self.spec.mode, "stations": list(self.spec.stations),
                **({"rsu": self.spec.rsu.resolved()} if self.spec.rsu is not None else {})}

    def _open_link(self, ctx: RunContext) -> rsu_link.RsuLink:
        from master.errors import SimulationError

        spec = self.spec.rsu
        try:
            self._sockets = rsu_link.LinkSockets(spec)
        except OSError as exc:
            raise SimulationError("v2x", ctx.t0, "[v2x] rsu link open",
                                  f"rsu = {str(spec.rsu)!r}, obu_listen = {str(spec.obu_listen)!r}: {exc} "
                                  f"(obu_listen must be an address of this host and a free UDP port)") from None
        link = rsu_link.RsuLink(spec, self._sockets.send, self._sockets.next_datagram, self.log,
                                lockstep=ctx.mode == "lockstep", t0=ctx.t0)
        link.kernel_timestamps = self._sockets.kernel_timestamps
        return link

    def _position(self, name: str, t: float) -> tuple[float, float, float]:
        st = self.spec.stations[name]
        if st.position is not None:
            return st.position
        x, y = self._getters[name]()[:2]
        return (float(x), float(y), 0.0)

    def _on_tx(self, msg) -> None:
        with self._lock:
            self._inbox.append(msg)

    def inject(self, station: str, payload: bytes, t: float) -> None:
        """A frame on the air as if `station` had sent it at t (scenario events): handed over here, in the
        master's thread, so it goes on the air in this step whatever the bus's delivery thread is doing."""
        self._injected += 1
        msg = _Injected(tx_key(station), t, f"event:{station}", self._injected, payload)
        with self._lock:
            self._inbox.append(msg)

    def after_step(self, k: int, t_next: float) -> None:
        with self._lock:
            inbox, self._inbox = self._inbox, []
        for msg in inbox:
            heapq.heappush(self._waiting, (msg.t_sim, msg.sender, msg.seq, next(self._order), msg))
        air = self.air
        # frames stamped up to the end of this step go on the air now; later ones wait for their time
        while self._waiting and self._waiting[0][0] <= t_next + 1e-12:
            msg = heapq.heappop(self._waiting)[-1]
            if msg.t_sim < self._t_done - 1e-9:
                self.late += 1
            station = msg.key.rsplit("/", 1)[-1]
            about = self._about(msg) if station in self.spec.stations else None
            t_tx = max(msg.t_sim, self._t_done)
            air.transmit(station, msg.seq, t_tx, msg.payload, msg.stamps, about)
            if self.link is not None and station == self.spec.rsu.rsu_station:
                self.link.transmit(station, msg.seq, t_tx, msg.payload, msg.stamps, about)
        deliveries = air.due(t_next)
        if self.link is not None:
            deliveries = sorted(deliveries + self.link.due(t_next), key=lambda d: d.arrival)
        for d in deliveries:
            self.bus.publish(rx_key(d.receiver), d.payload, d.arrival,
                             stamps={**d.stamps, AIR_ARRIVAL: stamp_ns(self._stamp_time(d.arrival))})
        self._t_done = t_next

    def _about(self, msg) -> dict[str, Any]:
        """The frame's `subject` and `frame_t` (the vehicles are placed at the frame's own time, t_sim)."""
        frame = (msg.stamps or {}).get(FRAME)
        frame_t = stamp_s(int(frame)) if isinstance(frame, (int, float)) and not isinstance(frame, bool) else None
        if self.subjects is None:
            return {"subject": None, "frame_t": frame_t}
        return self.subjects.about(msg.payload, float(msg.t_sim), frame_t)

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        if self._sub is not None:
            self._sub.close()
            self._sub = None
        if self._sockets is not None:
            self._sockets.close()
            self._sockets = None
        air = self.air
        return {"mode": self.spec.mode, **(air.counts if air else {}), "late": self.late,
                "in_flight_at_end": air.in_flight if air else 0,
                **(self.subjects.section() if self.subjects is not None else {}),
                **({"rsu": self.link.section()} if self.link is not None else {})}


def _subject_finder(ctx: RunContext):
    """The run's tie from frames to vehicles: the world's vehicles and geodetic origin (the scenario's
    [world] when the world hook is not open; without one, every FMU with x, y outputs and the default origin)."""
    from bridges.geo import GeoOrigin
    from bridges.j2735.codec import J2735Error
    from master.links.v2x_subject import SubjectFinder, world_bodies

    world = ctx.world
    layout = world.layout if world is not None else getattr(getattr(ctx, "scenario", None), "world", None)
    origin = getattr(layout, "origin", None) or GeoOrigin()
    try:
        return SubjectFinder(origin, world_bodies(ctx.fmus, layout))
    except J2735Error as exc:  # e.g. V2I_J2735_ASN1_DIR names unusable files: the air runs, frames get no subject
        ctx.events({"event": "v2x_subject_off", "t": ctx.t0, "reason": exc.reason})
        return None
