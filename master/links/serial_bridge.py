"""Serial bridges: an FMU's serial port exposed as a pyserial ``socket://host:port`` URL.

An application (the RSU app) opens the port with
``serial.serial_for_url("socket://127.0.0.1:PORT")`` in simulation and
``serial.Serial("/dev/ttyS0")`` on a real box, with the same code. The bridge is
a TCP server for one client at a time (RS-232 is point to point; a second client
waits in the listen backlog until the first disconnects).

Scenario file::

    [serial.tlc]
    instance = "tlc"                     # the FMU instance that owns the port
    listen = "socket://127.0.0.1:0"      # port 0: any free port (the URL is in metadata.json)
    rx = "serial_rx_hex"                 # String input: bytes from the client, hex (default)
    tx = "serial_tx_hex"                 # String output: bytes to the client, hex (default)
    tx_end_time = "serial_tx_end_time"   # Real output: when the last tx byte left the line (optional)
    idle = "serial_idle"                 # Boolean output: nothing in flight (needed by sync = "turn")
    sync = "turn"                        # lockstep: "turn" (default when `idle` exists) or "free"
    connect_timeout = 0.0                # wall s to wait for a client before the first step
    turn_timeout = 5.0                   # wall s a silent client may hold a turn
    collect_gap = 0.02                   # wall s of silence that ends a client's write

Data path: bytes the client sends are handed to the FMU's rx input at the next
communication point t_k of the instance (the FMU's UART model then times them
on the line); bytes the FMU reports in its tx output after the step are sent to
the client at once. Each chunk is logged to ``serial-<name>.jsonl`` in the run
folder with its simulated time (rx: t_k; tx: the step end and the FMU's exact
``tx_end_time``), so the simulated round trip of a request is
``tx.wire_end - rx.t``: the model's wire time plus its turnaround (ANCHORS S7).

Determinism (why ``sync``): in lockstep the master runs far faster than the wall
clock, so "the next step after the bytes arrived" would depend on machine speed.
With ``sync = "turn"`` the exchange is defined in simulated time instead: the
client and the link take turns. Whenever a client is connected and the FMU
reports the link ``idle`` (no byte on either line, no answer pending), the master
does not step until the client has written (its write ends after ``collect_gap``
of silence) or disconnected; the bytes enter at that communication point. So a
request sent after reading an answer enters at the first communication point after
the answer's last byte, whatever the wall-clock speed of the client, and its
processing time counts as zero simulated time (a fixed-latency policy of 0).
The wait comes at the end of the step that left the link idle, before the next
step's tick to the apps: a client that has written its next request has read
the answer, so an app dates the answer by that tick on any machine load. (A
client that writes only after a tick, which no app here does, would wait out
``turn_timeout`` each time the link goes idle: give it ``sync = "free"``.)
A client that stays silent for ``turn_timeout`` loses the turn: the master runs
free until it writes again (logged as ``turn_timeout``), so a client that never
polls cannot stall a run. With ``sync = "free"`` (always in realtime mode) the
master never waits: bytes enter at the first communication point after they
arrived in wall-clock time, as they would from a box on a real serial line.
"""
from __future__ import annotations

import re
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from master.events import EventLog
from master.errors import SimulationError
from master.hooks import Hook, Outcome, RunContext
from master.scenario.tables import Table

SYNC_MODES = ("turn", "free")
SERIAL_KEYS = ("instance", "listen", "rx", "tx", "tx_end_time", "idle", "sync", "connect_timeout",
               "turn_timeout", "collect_gap")
_DEFAULTS = {"rx": "serial_rx_hex", "tx": "serial_tx_hex", "tx_end_time": "serial_tx_end_time",
             "idle": "serial_idle"}
_URL = re.compile(r"^socket://(\[[^\]]+\]|[^:/\[\]]+):(\d+)$")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass
class SerialSpec:
    name: str
    instance: str
    listen: str
    host: str
    port: int
    rx: str
    tx: str
    tx_end_time: str | None
    idle: str | None
    sync: str
    connect_timeout: float = 0.0
    turn_timeout: float = 5.0
    collect_gap: float = 0.02

    def resolved(self) -> dict[str, Any]:
        out = {"instance": self.instance, "listen": self.listen, "rx": self.rx, "tx": self.tx, "sync": self.sync,
               "connect_timeout": self.connect_timeout, "turn_timeout": self.turn_timeout,
               "collect_gap": self.collect_gap}
        if self.tx_end_time:
            out["tx_end_time"] = self.tx_end_time
        if self.idle:
            out["idle"] = self.idle
        return out


def read_section(value: Any, context) -> dict[str, SerialSpec]:
    """The `[serial.NAME]` section's reader (master.scenario.sections)."""
    return parse_serial(value, context.instances, context.connections, context.problem)


def parse_serial(table: Any, instances: dict, connections: list, problem: Callable[[str, str], None]
                 ) -> dict[str, SerialSpec]:
    """Validate the `[serial.<name>]` tables; every problem goes to `problem(key, message)`."""
    ports = Table(table, "serial", problem, expected="a table of [serial.NAME] tables")
    driven = {(c.dst, c.dst_var): str(c) for c in connections}
    specs: dict[str, SerialSpec] = {}
    used_rx: dict[tuple[str, str], str] = {}
    used_ports: dict[tuple[str, int], str] = {}
    for name in ports.raw:
        if not _NAME.match(name):
            ports.problem(name, "serial port names must be identifiers (letters, digits, _; no dots)")
            continue
        t = ports.sub(name)
        if not t.ok:
            continue
        t.unknown_keys(SERIAL_KEYS)
        inst = t.instance("instance", instances, "the name of the FMU instance that owns the serial port")
        if inst is None:
            continue
        inst_name = inst.name
        listen = t.get("listen", "socket://127.0.0.1:0")
        match = _URL.match(listen) if isinstance(listen, str) else None
        if not match or not 0 <= int(match.group(2)) <= 65535:
            t.problem("listen", f"expected \"socket://HOST:PORT\" (PORT 0-65535, 0 = any free port), got {listen!r}")
            host, port = "127.0.0.1", 0
        else:
            host, port = match.group(1).strip("[]"), int(match.group(2))
        rx = t.fmu_variable("rx", inst, causality="input", family="string", default=_DEFAULTS["rx"])
        tx = t.fmu_variable("tx", inst, causality="output", family="string", default=_DEFAULTS["tx"])
        tx_end = t.fmu_variable("tx_end_time", inst, causality="output", family="real",
                                default=_DEFAULTS["tx_end_time"], required=False)
        idle = t.fmu_variable("idle", inst, causality="output", family="boolean", default=_DEFAULTS["idle"],
                              required=False)
        if rx is not None:
            if (inst_name, rx) in driven:
                t.problem("rx", f"{inst_name}.{rx} is already driven by {driven[(inst_name, rx)]}")
            if (inst_name, rx) in used_rx:
                t.problem("rx", f"{inst_name}.{rx} is already the rx of serial.{used_rx[(inst_name, rx)]}")
            used_rx[(inst_name, rx)] = name
        if port and (host, port) in used_ports:
            t.problem("listen", f"{listen} is already used by serial.{used_ports[(host, port)]}")
        used_ports[(host, port)] = name
        sync = t.choice("sync", SYNC_MODES, "turn" if idle else "free")  # a bad one falls back to the default
        if sync == "turn" and not idle:
            t.problem("sync", "\"turn\" needs an idle output (set idle = \"...\") or use sync = \"free\"")
        numbers = {}
        for k, default, positive in (("connect_timeout", 0.0, False), ("turn_timeout", 5.0, True),
                                     ("collect_gap", 0.02, True)):
            numbers[k] = t.number(k, default, low=0, high=3600, expected="wall-clock seconds 0..3600")
            if positive and numbers[k] == 0:
                t.problem(k, f"must be > 0, got {t.get(k)!r}")
        if not t.ok or rx is None or tx is None:
            continue
        specs[name] = SerialSpec(name, inst_name, listen, host, port, rx, tx, tx_end, idle, sync, **numbers)
    return specs


class SerialBridge:
    """One port: a TCP server thread collecting client bytes, stepped by the master thread."""

    def __init__(self, spec: SerialSpec, fmu, multiple: int, sync: str, run_dir: Path, quiet: bool = True):
        self.spec = spec
        self.fmu = fmu
        self.multiple = multiple
        self.sync = sync
        self.quiet = quiet
        self.url = ""
        self._events_path = Path(run_dir) / f"serial-{spec.name}.jsonl"
        self._events = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._inbox = bytearray()
        self._last_rx_wall = 0.0
        self._conn: socket.socket | None = None
        self._server: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._rx_nonempty = False  # the rx input holds bytes (must be cleared before the next step)
        self._link_idle = True
        self._turn_lost = False
        self._last_rx_t: float | None = None
        self.stats = {"url": "", "sync": sync, "clients": 0, "bytes_to_fmu": 0, "bytes_to_client": 0,
                      "chunks_to_fmu": 0, "chunks_to_client": 0, "bytes_dropped_no_client": 0,
                      "turn_waits": 0, "turn_wait_wall_s": 0.0, "turn_timeouts": 0,
                      "events": self._events_path.name}

    # -- set-up -----------------------------------------------------------------------
    def open(self, t: float) -> str:
        fmu, spec = self.fmu, self.spec

        def getter(name, fam):
            return fmu.accessor(fam, [fmu.variables[name].valueReference], setter=False) if name else None

        self._set_rx = fmu.accessor(fmu.access_key(spec.rx), [fmu.variables[spec.rx].valueReference], setter=True)
        self._get_tx = getter(spec.tx, fmu.access_key(spec.tx))
        self._get_end = getter(spec.tx_end_time, fmu.access_key(spec.tx_end_time) if spec.tx_end_time else None)
        self._get_idle = getter(spec.idle, fmu.access_key(spec.idle) if spec.idle else None)
        if self._get_idle is not None:
            self._link_idle = bool(self._get_idle()[0])
        try:
            family_ = socket.AF_INET6 if ":" in spec.host else socket.AF_INET
            self._server = socket.create_server((spec.host, spec.port), family=family_, backlog=4)
        except OSError as exc:
            raise SimulationError(spec.instance, t, f"serial bridge {spec.name!r} listen",
                                  f"cannot listen on {spec.listen}: {exc}") from exc
        self._server.settimeout(0.1)
        host = f"[{spec.host}]" if ":" in spec.host else spec.host
        self.url = f"socket://{host}:{self._server.getsockname()[1]}"
        self.stats["url"] = self.url
        self._events = EventLog(self._events_path.parent, self._events_path.name, "w")
        self._log({"t": t, "event": "listen", "url": self.url, "sync": self.sync})
        self._thread = threading.Thread(target=self._serve, name=f"serial-{spec.name}", daemon=True)
        self._thread.start()
        if not self.quiet:
            print(f"serial port {spec.name} ({spec.instance}): {self.url}  [sync {self.sync}]", file=sys.stderr)
        return self.url

    def wait_for_client(self, t: float) -> None:
        timeout = self.spec.connect_timeout
        if timeout <= 0:
            return
        with self._cond:
            if not self._cond.wait_for(lambda: self._conn is not None, timeout):
                self._log({"t": t, "event": "no_client", "waited_s": timeout})

    # -- server thread ------------------------------------------------------------------
    def _serve(self) -> None:
        server = self._server
        while not self._stop.is_set():
            try:
                conn, peer = server.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            conn.settimeout(0.1)
            with self._cond:
                self._conn = conn
                self.stats["clients"] += 1
                self._turn_lost = False
                self._cond.notify_all()
            self._log({"event": "connect", "peer": str(peer[0]), "t": self.fmu.time})
            while not self._stop.is_set():
                try:
                    data = conn.recv(65536)
                except socket.timeout:
                    continue
                except OSError:
                    data = b""
                with self._cond:
                    if not data:
                        self._conn = None
                        self._cond.notify_all()
                        break
                    self._inbox += data
                    self._last_rx_wall = time.monotonic()
                    self._cond.notify_all()
            self._log({"event": "disconnect", "t": self.fmu.time})
            try:
                conn.close()
            except OSError:
                pass

    # -- stepping (master thread) ---------------------------------------------------------
    def before_step(self, t: float) -> None:
        """Hand the client's bytes to the FMU at communication point t (waiting for them under sync = turn)."""
        with self._cond:
            self._await_turn_locked(t)  # the first step's (after_step waits for every later one)
            if self._inbox and self.sync == "turn":
                gap = self.spec.collect_gap  # the client's write ends after `gap` of silence
                while self._conn is not None:
                    quiet = time.monotonic() - self._last_rx_wall
                    if quiet >= gap:
                        break
                    self._cond.wait(gap - quiet)
            data = bytes(self._inbox)
            self._inbox.clear()
        if data:
            self._turn_lost = False
            self._set_rx([data.hex()])
            self._rx_nonempty = True
            self._last_rx_t = t
            self.stats["bytes_to_fmu"] += len(data)
            self.stats["chunks_to_fmu"] += 1
            self._log({"t": t, "event": "rx", "n": len(data), "hex": data.hex()})
        elif self._rx_nonempty:
            self._set_rx([""])
            self._rx_nonempty = False

    def _await_turn_locked(self, t: float) -> None:
        """Under sync = turn, while the link is idle: wait for the client's write (or its disconnect); a client
        silent for turn_timeout loses the turn."""
        if self.sync == "turn" and self._link_idle and not self._turn_lost and self._conn is not None \
                and not self._inbox:
            self.stats["turn_waits"] += 1
            w0 = time.monotonic()
            got = self._cond.wait_for(lambda: self._inbox or self._conn is None, self.spec.turn_timeout)
            self.stats["turn_wait_wall_s"] += time.monotonic() - w0
            if not got:
                self._turn_lost = True
                self.stats["turn_timeouts"] += 1
                self._log({"t": t, "event": "turn_timeout", "waited_s": self.spec.turn_timeout})

    def after_step(self, t_next: float) -> None:
        """Send what the FMU transmitted during the step to the client; under sync = turn, once the link is
        idle, wait for the client's next write here, before the next step's tick.

        Why here and not only in before_step: the apps' tick (the participants hook) comes before this hook's
        before_step, and the answer's bytes (TCP) and the tick (the bus) take different sockets, so a loaded
        machine can deliver the tick first and the app dates the answer a step late (the EVSP case's "granted"
        moved by 10 ms between two runs). A client that reads an answer and writes its next request has the
        answer in hand before its write: waiting for the write makes the answer the tick's."""
        if self._get_idle is not None:
            self._link_idle = bool(self._get_idle()[0])
        self._send_tx(t_next)
        with self._cond:
            self._await_turn_locked(t_next)

    def _send_tx(self, t_next: float) -> None:
        raw = self._get_tx()[0]
        text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw or "")
        if not text:
            return
        try:
            data = bytes.fromhex(text)
        except ValueError:
            raise SimulationError(self.spec.instance, t_next, f"serial bridge {self.spec.name!r}",
                                  f"{self.spec.tx} is not hexadecimal bytes: {text[:40]!r}") from None
        event = {"t": t_next, "event": "tx", "n": len(data), "hex": data.hex()}
        if self._get_end is not None:
            event["wire_end"] = float(self._get_end()[0])
        if self._last_rx_t is not None:
            event["last_rx_t"] = self._last_rx_t
        with self._cond:
            conn = self._conn
        if conn is None:
            self.stats["bytes_dropped_no_client"] += len(data)
            event["dropped"] = True
        else:
            try:
                conn.sendall(data)
                self.stats["bytes_to_client"] += len(data)
                self.stats["chunks_to_client"] += 1
            except OSError as exc:
                self.stats["bytes_dropped_no_client"] += len(data)
                event["dropped"] = f"{type(exc).__name__}: {exc}"
        self._log(event)

    def inject(self, data: bytes, to: str, t: float) -> int:
        """Bytes on the line as if it carried them (scenario events): to the FMU's rx at this communication
        point, or to the connected client now; logged like the real traffic. Returns the bytes delivered."""
        if to == "fmu":
            with self._cond:
                self._inbox += data
                self._last_rx_wall = time.monotonic() - self.spec.collect_gap  # complete already: no wait
            self._log({"t": t, "event": "inject", "to": "fmu", "n": len(data)})
            return len(data)
        with self._cond:
            conn = self._conn
        if conn is None:
            self._log({"t": t, "event": "inject", "to": "client", "n": 0, "why": "no client"})
            return 0
        try:
            conn.sendall(data)
        except OSError as exc:
            self._log({"t": t, "event": "inject", "to": "client", "n": 0, "why": str(exc)})
            return 0
        self._log({"t": t, "event": "inject", "to": "client", "n": len(data)})
        return len(data)

    def close(self) -> dict[str, Any]:
        self._stop.set()
        if self._server is not None:
            try:
                self._server.close()
            except OSError:
                pass
        with self._cond:
            conn = self._conn
        if conn is not None:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._events is not None:
            self._events.close()
            self._events = None
        return dict(self.stats)

    def _log(self, event: dict[str, Any]) -> None:
        events = self._events
        if events is not None:  # EventLog ignores lines after close (the server thread may still log)
            events(event)


class SerialBridges(Hook):
    """All serial ports of a run, as one hook of the loop; inert (and free) when the scenario has none."""

    name = "serial"

    def __init__(self, specs: dict[str, SerialSpec] | None, mode: str, quiet: bool = True):
        self.specs = dict(specs or {})
        self.mode = mode
        self.quiet = quiet
        self.bridges: list[SerialBridge] = []
        self.urls: dict[str, str] = {}
        self.ready = threading.Event()  # set once every port listens (tests and launchers wait on it)

    def __bool__(self) -> bool:
        return bool(self.specs)

    def open(self, ctx: RunContext) -> dict[str, Any]:
        t = ctx.t0
        for spec in self.specs.values():
            member = ctx.members[spec.instance]
            sync = spec.sync if self.mode == "lockstep" else "free"
            bridge = SerialBridge(spec, member.fmu, member.multiple, sync, ctx.run_dir, self.quiet)
            self.bridges.append(bridge)
            self.urls[spec.name] = bridge.open(t)
        ctx.serial_urls.update(self.urls)  # started apps find them in their environment
        self.ready.set()
        for bridge in self.bridges:
            bridge.wait_for_client(t)
        return {b.spec.name: dict(b.stats) for b in self.bridges}

    def before_step(self, k: int, t: float) -> None:
        for b in self.bridges:
            if k % b.multiple == 0:
                b.before_step(t)

    def after_step(self, k: int, t_next: float) -> None:
        for b in self.bridges:
            if k % b.multiple == 0:
                b.after_step(t_next)

    def close(self, outcome: Outcome | None = None) -> dict[str, Any]:
        return {b.spec.name: b.close() for b in self.bridges}
