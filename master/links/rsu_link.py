"""Real radios in the loop: the V2X air's link from an RSU station to an OBU station through real devices.

With ``[v2x] mode = "rsu"`` the frames the RSU app transmits leave the
simulation as USDOT RSU 4.1 Immediate Forward records (bridges.immediate_forward)
to a roadside unit's UDP port, and what an on-board unit forwards back, to a
UDP port of the master, reaches the AV app as if the simulated air had
delivered it, with the time it took on the real radio. The emulated box
(``python -m bridges.rsu_box``) stands in for both devices in tests and demos.
Every other link of the air (other stations) stays on the channel model.

    [v2x]
    mode = "rsu"
    rsu = "192.0.2.10:1516"          # the RSU's Immediate Forward port (required, no default)
    obu_listen = "192.0.2.1:47900"   # where the OBU forwards what it hears (required, no default)
    rsu_station = "rsu"              # the station whose frames the RSU broadcasts
    obu_station = "cav"              # the station the OBU's forwards are delivered to
    obu_format = "ieee1609dot2"      # bare | ieee1609dot2 | immediate-forward | immediate-forward-1609dot2
    signature = "ours"               # our 1609.2 envelope in the payload, Signature=False; or "rsu":
                                     # the bare MessageFrame, Signature=True (the RSU signs)
    forward_timeout_s = 0.5          # a frame not forwarded back within this (wall clock) is lost
    tx_mode = "CONT"                 # or "ALT"
    [v2x.messages.map]               # per kind (bsm, surrogate_bsm, spat, map, ssm, srm): psid, channel, priority
    psid = "0x8002"

Time. In **lockstep** the record is sent when the frame goes on the air (at
its simulation time t_tx, wall time w_tx), and the forward that comes back at
wall time w_rx is delivered at simulation time t_tx + (w_rx - w_tx): the AV app
sees the real box's delay. To keep that exact the step ending at t_next waits,
for each frame still out, until it is back or until it could no longer arrive
by t_next (wall w_tx + (t_next - t_tx)); a frame not back after
`forward_timeout_s` is lost. So a run with frames in flight is paced no faster
than the wall clock, and the structure of the run (what arrives at which step)
depends only on the measured delays. In **realtime** nothing waits: a forward
is delivered at the simulation time of the step that takes it.

Matching. A forward is tied to the frame it carries by the J2735 MessageFrame
found in it (the format says where; bridges.obu_forward): the oldest frame
still out with those bytes. The AV app then receives the frame as the RSU app
published it (its own 1609.2 envelope) with its trace stamps and AIR_ARRIVAL,
so the latency chain in metrics.json includes the real radio. A forward that
matches no frame sent is a *foreign* frame (another radio on the air):
delivered as it came (a bare frame wrapped as unsecured 1609.2 data, which the
AV app's policy decides on), and counted. Late (after the timeout) and
duplicate forwards are counted and dropped; datagrams the format cannot read
are counted by reason. Nothing a device sends ends the run.

Events (events.jsonl): ``v2x_forwarded`` (the record sent), ``v2x_delivered``
(with ``via = "rsu"`` and the wall delay) and ``v2x_dropped`` (reason
``timeout`` or ``not_sent``) for the link, so the metrics' pdr, air latency
and age of information work as with the channel model; ``v2x_obu_refused``,
``v2x_foreign``, ``v2x_late``, ``v2x_duplicate`` for the rest.
"""
from __future__ import annotations

import queue
import socket
import threading
import time
from collections import Counter, OrderedDict, deque
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

from bridges import immediate_forward as imf
from bridges import obu_forward
from bridges.security import oer
from bridges.udp_endpoint import Endpoint, enable_rx_timestamps, parse_endpoint, recv_stamped, udp_socket
from master.scenario.tables import Table, did_you_mean

KEYS = ("rsu", "obu_listen", "rsu_station", "obu_station", "obu_format", "signature", "forward_timeout_s",
        "tx_mode", "messages")
REQUIRED = ("rsu", "obu_listen", "rsu_station", "obu_station")
SIGNATURES = ("ours", "rsu")
SETTLED_MEMORY = 4096  # frames delivered or lost that a late or duplicate forward is recognised by
WALL_EPS_S = 1e-6  # wall-clock comparisons: a bound reached to within a microsecond is reached


@dataclass
class RsuLinkSpec:
    rsu: Endpoint
    obu_listen: Endpoint
    rsu_station: str
    obu_station: str
    obu_format: str = "ieee1609dot2"
    signature: str = "ours"
    forward_timeout_s: float = 0.5
    tx_mode: str = "CONT"
    routes: imf.RouteTable = field(default_factory=imf.default_routes)

    def resolved(self) -> dict[str, Any]:
        """The keys as the [v2x] table writes them (parse_link reads them back to an equal spec)."""
        return {"rsu": str(self.rsu), "obu_listen": str(self.obu_listen), "rsu_station": self.rsu_station,
                "obu_station": self.obu_station, "obu_format": self.obu_format, "signature": self.signature,
                "forward_timeout_s": self.forward_timeout_s, "tx_mode": self.tx_mode,
                "messages": self.routes.describe()}


def parse_link(t: Table, stations: Iterable[str], technology: str) -> RsuLinkSpec | None:
    """The real-radio keys of `[v2x]` (mode = "rsu"); every problem reported through `t`."""
    stations = list(stations)
    endpoints = {}
    for key in ("rsu", "obu_listen"):
        if key not in t:
            t.problem(key, f"required with mode = \"rsu\": \"HOST:PORT\" of {'the RSU' if key == 'rsu' else 'this master'}"
                           " (no default: the address is your device's)")
            continue
        try:
            endpoints[key] = parse_endpoint(t.get(key))
        except ValueError as exc:
            t.problem(key, str(exc))
    names = {}
    for key in ("rsu_station", "obu_station"):
        name = t.string(key, required=True, expected=f"a station of [v2x.stations] ({', '.join(stations)})")
        if name is None:
            continue
        if name not in stations:
            hint = did_you_mean(name, stations)
            t.problem(key, f"no station {name!r} in [v2x.stations] (stations: {', '.join(stations)})"
                           + (f"; {hint}" if hint else ""))
            continue
        names[key] = name
    if len(names) == 2 and names["rsu_station"] == names["obu_station"]:
        t.problem("obu_station", "must be another station than rsu_station")
    fmt = t.choice("obu_format", obu_forward.formats(), "ieee1609dot2")
    signature = t.choice("signature", SIGNATURES, "ours")
    timeout = t.number("forward_timeout_s", 0.5, low=0, high=10, low_open=True, expected="a number in (0, 10] s")
    tx_mode = t.choice("tx_mode", imf.TX_MODES, "CONT")
    channel = imf.CV2X_CHANNEL if technology == "cv2x" else imf.DSRC_CHANNEL
    messages = t.sub("messages", "a table of message kinds")
    routes = imf.default_routes(channel)
    if messages.ok:
        routes = routes.with_overrides(messages.raw, lambda key, reason: messages.problem(key or None, reason))
    if not t.ok:
        return None
    return RsuLinkSpec(endpoints["rsu"], endpoints["obu_listen"], names["rsu_station"], names["obu_station"],
                       fmt, signature, timeout, tx_mode, routes)


# -- the core: records out, forwards in, deliveries at their times (no sockets) ------------------------------
@dataclass
class Delivery:
    """A frame due at a receiver at `arrival`, from the simulated air (master.links.radio_bridge.Air) or this link."""

    receiver: str
    sender: str
    seq: int
    t_tx: float
    arrival: float
    payload: bytes
    stamps: dict
    about: dict = field(default_factory=dict)


@dataclass
class _Out:
    """A frame sent to the RSU and not yet settled."""

    sender: str
    seq: int
    t_tx: float
    wall_tx: float
    payload: bytes  # as the app published it: what the AV app receives
    frame: bytes    # the UPER MessageFrame: what a forward is matched by
    stamps: dict
    about: dict
    wall_rx: float | None = None
    arrival: float | None = None


def _with(event: dict, about: dict | None) -> dict:
    for key, value in (about or {}).items():
        event.setdefault(key, value)
    return event


class RsuLink:
    """The link's logic. `send(record bytes)` gives a record to the RSU (OSError: not sent);
    `next_datagram(timeout)` gives the next forward the OBU sent, `(wall time received, bytes, source)`,
    or None after `timeout` seconds; `clock()` is the wall clock those times are on (time.time: the clock
    of the kernel's receive timestamps)."""

    def __init__(self, spec: RsuLinkSpec, send: Callable[[bytes], None],
                 next_datagram: Callable[[float], tuple[float, bytes, str] | None],
                 log: Callable[[dict], None] | None = None, clock: Callable[[], float] = time.time,
                 lockstep: bool = True, t0: float = 0.0):
        self.spec = spec
        self.fmt = obu_forward.get_format(spec.obu_format)
        self.send, self.next_datagram, self.clock, self.lockstep = send, next_datagram, clock, lockstep
        self.log = log or (lambda event: None)
        self._out: dict[bytes, deque[_Out]] = {}
        self._back: list[_Out] = []  # returned, waiting for their arrival time
        self._settled: OrderedDict[bytes, str] = OrderedDict()
        self._t_floor = t0  # the end of the last step: no delivery is earlier
        self.counts: Counter = Counter()
        self.not_sent: Counter = Counter()
        self.refused: Counter = Counter()
        self.delays_ms: list[float] = []
        self.held_s = 0.0
        self.kernel_timestamps: bool | None = None  # set by the socket adapter's owner, for the record

    # -- out -------------------------------------------------------------------------------------------------
    def transmit(self, sender: str, seq: int, t_tx: float, payload: bytes, stamps: dict | None = None,
                 about: dict | None = None) -> None:
        """The RSU station put a frame on the air at t_tx: an Immediate Forward record to the RSU."""
        about = dict(about or {})
        spec = self.spec
        try:
            frame, psid, _ = obu_forward.open_envelope(payload)
        except obu_forward.ForwardError:
            frame, psid = bytes(payload), None  # not 1609.2 data: the app sent the frame itself
        try:
            route = spec.routes.for_frame(imf.message_id(frame), psid)
        except ValueError as exc:
            return self._not_sent(sender, seq, t_tx, about, "not-j2735", str(exc))
        if route is None:
            return self._not_sent(sender, seq, t_tx, about, "no-route",
                                  f"J2735 message {imf.message_id(frame)} is in no route of the table")
        if spec.signature == "ours":
            if psid is not None and psid != route.psid_value:
                return self._not_sent(sender, seq, t_tx, about, "psid-mismatch",
                                      f"the envelope is signed for PSID {psid:#x}, the {route.kind} route sends "
                                      f"{imf.format_psid(route.psid)} (PSID {route.psid_value:#x})")
            body, signature = bytes(payload), False
        else:
            body, signature = frame, True
        record = imf.Record(route.type, route.psid, body, tx_channel=route.channel, priority=route.priority,
                            tx_mode=spec.tx_mode, signature=signature)
        try:
            data = imf.write(record, spec.routes)
        except imf.RecordError as exc:
            return self._not_sent(sender, seq, t_tx, about, exc.reason.value, exc.detail)
        wall = self.clock()  # before the send: the delay measured is never shorter than the devices'
        try:
            self.send(data)
        except OSError as exc:
            return self._not_sent(sender, seq, t_tx, about, "send-error", str(exc))
        self.counts["records_sent"] += 1
        self._out.setdefault(frame, deque()).append(_Out(sender, seq, t_tx, wall, bytes(payload), frame,
                                                         dict(stamps or {}), about))
        self.log(_with({"event": "v2x_forwarded", "t": t_tx, "from": sender, "to": spec.obu_station, "seq": seq,
                        "rsu": str(spec.rsu), "type": route.type, "kind": route.kind,
                        "psid": imf.format_psid(route.psid), "channel": route.channel, "signature": signature,
                        "bytes": len(data)}, about))

    def _not_sent(self, sender: str, seq: int, t_tx: float, about: dict, reason: str, detail: str) -> None:
        self.counts["not_sent"] += 1
        self.not_sent[reason] += 1
        self.log(_with({"event": "v2x_dropped", "t": t_tx, "from": sender, "to": self.spec.obu_station, "seq": seq,
                        "reason": "not_sent", "detail": f"{reason}: {detail}"}, about))

    # -- in --------------------------------------------------------------------------------------------------
    def due(self, t_next: float) -> list[Delivery]:
        """The forwards due by t_next, in arrival order (lockstep: after waiting as the module says)."""
        foreign: list[Delivery] = []
        self._drain(t_next, foreign)
        if self.lockstep:
            while True:
                now = self.clock()
                self._expire(now)
                until = self._must_wait_until(t_next)
                if until is None or until <= now + WALL_EPS_S:
                    break
                item = self.next_datagram(until - now)
                self.held_s += self.clock() - now
                if item is not None:
                    self._offer(item, t_next, foreign)
                    self._drain(t_next, foreign)
        else:
            self._expire(self.clock())
        ready = sorted((o for o in self._back if o.arrival <= t_next + 1e-12), key=lambda o: (o.arrival, o.wall_rx))
        self._back = [o for o in self._back if o.arrival > t_next + 1e-12]
        out = []
        for o in ready:
            self.counts["delivered"] += 1
            delay = o.wall_rx - o.wall_tx
            self.delays_ms.append(delay * 1e3)
            self.log(_with({"event": "v2x_delivered", "t": o.arrival, "from": o.sender, "to": self.spec.obu_station,
                            "seq": o.seq, "t_tx": o.t_tx, "latency_s": o.arrival - o.t_tx, "via": "rsu",
                            "wall_delay_s": round(delay, 6)}, o.about))
            self._settle(o.frame, "delivered")
            out.append(Delivery(self.spec.obu_station, o.sender, o.seq, o.t_tx, o.arrival, o.payload, o.stamps,
                                    o.about))
        self._t_floor = t_next
        return sorted(out + foreign, key=lambda d: d.arrival)

    def _must_wait_until(self, t_next: float) -> float | None:
        """The latest wall time a frame still out could come back and be due by t_next (None: none could)."""
        until = None
        for outs in self._out.values():
            for o in outs:
                ahead = t_next - o.t_tx
                if ahead < 0:
                    continue
                w = o.wall_tx + min(ahead, self.spec.forward_timeout_s)
                until = w if until is None else max(until, w)
        return until

    def _drain(self, t_now: float, foreign: list) -> None:
        while (item := self.next_datagram(0.0)) is not None:
            self._offer(item, t_now, foreign)

    def _offer(self, item: tuple[float, bytes, str], t_now: float, foreign: list) -> None:
        wall, data, source = item
        self.counts["forwards_received"] += 1
        try:
            found = self.fmt.read(data, self.spec.routes)
        except obu_forward.ForwardError as exc:
            self.counts["obu_refused"] += 1
            self.refused[exc.reason] += 1
            self.log({"event": "v2x_obu_refused", "t": t_now, "from": source, "bytes": len(data),
                      "reason": exc.reason, "detail": exc.detail[:300]})
            return
        outs = self._out.get(found.frame)
        if outs:
            o = outs.popleft()
            if not outs:
                del self._out[found.frame]
            o.wall_rx = wall
            if self.lockstep:
                o.arrival = o.t_tx + (wall - o.wall_tx)
                if o.arrival < self._t_floor:  # stamped before the last step ended but taken after it
                    self.counts["arrival_clamped"] += 1
                    o.arrival = self._t_floor
            else:
                o.arrival = max(o.t_tx, t_now)
            self._back.append(o)
            return
        settled = self._settled.get(found.frame)
        if settled is not None:
            kind = "late" if settled == "lost" else "duplicate"
            self.counts[kind] += 1
            self.log({"event": f"v2x_{kind}", "t": t_now, "from": source, "bytes": len(data)})
            return
        self.counts["foreign"] += 1
        arrival = t_now  # no send time to measure from: the step that takes it
        payload = found.envelope if found.envelope is not None else oer.unsecured(found.frame)
        self.log({"event": "v2x_foreign", "t": arrival, "from": source, "to": self.spec.obu_station,
                  "bytes": len(data), "psid": found.psid})
        foreign.append(Delivery(self.spec.obu_station, f"obu:{source}", -1, arrival, arrival, payload, {}))

    def _expire(self, now: float) -> None:
        for frame in list(self._out):
            outs = self._out[frame]
            while outs and now - outs[0].wall_tx >= self.spec.forward_timeout_s - WALL_EPS_S:
                o = outs.popleft()
                self.counts["lost"] += 1
                self.log(_with({"event": "v2x_dropped", "t": o.t_tx, "from": o.sender, "to": self.spec.obu_station,
                                "seq": o.seq, "reason": "timeout",
                                "detail": f"not forwarded back within {self.spec.forward_timeout_s:g} s"}, o.about))
                self._settle(frame, "lost")
            if not outs:
                del self._out[frame]

    def _settle(self, frame: bytes, how: str) -> None:
        self._settled[frame] = how
        self._settled.move_to_end(frame)
        while len(self._settled) > SETTLED_MEMORY:
            self._settled.popitem(last=False)

    @property
    def in_flight(self) -> int:
        return sum(len(v) for v in self._out.values()) + len(self._back)

    def section(self) -> dict[str, Any]:
        """What the run's metadata says of the link: counts, reasons, the measured delays, the wait."""
        d = sorted(self.delays_ms)
        keys = ("records_sent", "not_sent", "forwards_received", "delivered", "lost", "late", "duplicate", "foreign",
                "obu_refused", "arrival_clamped")
        return {"rsu": str(self.spec.rsu), "obu_listen": str(self.spec.obu_listen), "link":
                f"{self.spec.rsu_station}->{self.spec.obu_station}", "obu_format": self.spec.obu_format,
                "signature": self.spec.signature, **{k: self.counts.get(k, 0) for k in keys},
                "not_sent_by_reason": dict(sorted(self.not_sent.items())),
                "obu_refused_by_reason": dict(sorted(self.refused.items())),
                "in_flight_at_end": self.in_flight, "held_wall_s": round(self.held_s, 4),
                "kernel_timestamps": self.kernel_timestamps,
                "wall_delay_ms": {"p50": d[len(d) // 2] if d else None, "min": d[0] if d else None,
                                  "max": d[-1] if d else None, "n": len(d)}}


# -- the sockets ---------------------------------------------------------------------------------------------
class LinkSockets:
    """A UDP socket to the RSU and one bound to `obu_listen`, read by a thread. Each datagram carries the
    kernel's receive time (time.time clock; bridges.udp_endpoint.recv_stamped), so the delay measured is
    the devices' even when the thread runs late (the master's thread holds the GIL through a camera render)."""

    def __init__(self, spec: RsuLinkSpec):
        self.spec = spec
        self._tx, self._rsu = udp_socket(spec.rsu, bind=False)
        try:
            self._rx, _ = udp_socket(spec.obu_listen, bind=True)
        except OSError:
            self._tx.close()
            raise
        self._rx.settimeout(0.2)
        self.kernel_timestamps = enable_rx_timestamps(self._rx)
        self._queue: queue.Queue = queue.Queue()
        self._closed = threading.Event()
        self.receive_errors = 0
        self._thread = threading.Thread(target=self._listen, name="v2x-obu-listen", daemon=True)
        self._thread.start()

    def _listen(self) -> None:
        while not self._closed.is_set():
            try:
                data, source, received = recv_stamped(self._rx)
            except socket.timeout:
                continue
            except OSError:
                if self._closed.is_set():
                    return
                self.receive_errors += 1
                time.sleep(0.01)
                continue
            self._queue.put((received, data, str(Endpoint(*source[:2]))))

    def send(self, data: bytes) -> None:
        self._tx.sendto(data, self._rsu)

    def next_datagram(self, timeout: float) -> tuple[float, bytes, str] | None:
        try:
            return self._queue.get(timeout=timeout) if timeout > 0 else self._queue.get_nowait()
        except queue.Empty:
            return None

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=1.0)
        for sock in (self._tx, self._rx):
            sock.close()
