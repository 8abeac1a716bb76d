"""The AB3418 serial link to the traffic-light controller: polled back to back, as a box polls /dev/ttyS0.

The link opens a pyserial URL (`socket://HOST:PORT` from the master's serial
bridge, `/dev/ttyS0` on a box) and keeps one status request in flight: as soon
as an answer is complete the next request goes out. That is also what the
master's serial bridge needs in lockstep (`sync = "turn"`): while the link is
idle it waits for the client's next write, so a request sent right after an
answer enters the controller at the communication point after the answer's
last byte, whatever the wall-clock speed of either side.

A background thread writes requests and watches the port; `collect()` (the
app's tick thread) reads whatever has arrived and returns the completed
answers. Because the master sends an answer's bytes before it publishes the
next tick, the answers `collect()` returns at a tick are the ones the
controller had finished by then: the app dates them by that tick.

Preemption (`set_preempt(on)`): the app asks for the emergency-vehicle call
(AB3418 SetPreempt, this project's 0x9B) and the link sends that frame in place
of the next poll, so it travels the same RS-232 line (its bytes cost wire time
in the controller's UART model) and its acknowledgement comes back the same
way; `collect_preempt()` returns the acknowledgements with the frame sizes, so
the app can charge the request's wire time to the request-to-green chain.

Every problem is counted and logged, never raised: bad frames by kind (garbage,
truncated, FCS, oversize), error answers, answers of the wrong type, polls
without an answer within `answer_timeout_s`, disconnects. After three
unanswered polls in a row the controller counts as lost until it answers again.

The timeout runs on the clock the controller lives in: wall time on a real line
and in a realtime run, the app's simulation time in lockstep (`follow(clock)`).
In lockstep a wall-clock timeout would count a master that is merely slow (a
loaded machine, a camera frame being rendered) as a silent controller, and the
duplicate request it then sends would change what goes over the wire.
"""
from __future__ import annotations

import logging
import re
import select
import threading
import time
from collections import Counter
from dataclasses import dataclass

from bridges import ab3418

log = logging.getLogger(__name__)
LOST_AFTER = 3  # consecutive unanswered polls
RECONNECT_S = 1.0
_POLLS = {"long": ab3418.GET_LONG_STATUS8, "short": ab3418.GET_SHORT_STATUS}


def serial_env(name: str) -> str:
    """The environment variable in which the master gives a started app serial port `name`'s URL."""
    return "V2I_SERIAL_" + re.sub(r"[^A-Za-z0-9]", "_", name).upper()


@dataclass
class PreemptAck:
    on: bool               # the call that was acknowledged
    request_bytes: int     # framed bytes of the SetPreempt request on the line
    answer_bytes: int      # framed bytes of the acknowledgement
    ok: bool               # False: the controller answered with an error
    wall: float            # time.monotonic() when the acknowledgement was complete


@dataclass
class StatusAnswer:
    status: ab3418.LongStatus8 | ab3418.ShortStatus
    wire_bytes: int        # framed bytes of the answer on the line (its wire time: wire_bytes * 10 / baud)
    wall: float            # time.monotonic() when it was complete


class ControllerLink:
    def __init__(self, url: str, station: int = 1, baud: int = 9600, poll: str = "long",
                 answer_timeout_s: float = 1.0, opener=None):
        self.url, self.station, self.baud = url, station, baud
        self.request_type = _POLLS[poll]
        self.answer_type = ab3418.response_type(self.request_type)
        self.request = ab3418.request(self.request_type, station)
        self.answer_timeout_s = answer_timeout_s
        self._opener = opener
        self._clock = time.monotonic  # what answer_timeout_s is measured on (follow() changes it)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._port = None
        self._decoder = ab3418.FrameDecoder()
        self._answers: list[StatusAnswer] = []
        self._preempt_wanted: bool | None = None    # a SetPreempt still to send (None: nothing to send)
        self._preempt_in_flight: tuple[bool, int] | None = None  # (on, request bytes) awaiting its answer
        self._preempt_acks: list[PreemptAck] = []
        self._outstanding_since: float | None = None
        self._consecutive_timeouts = 0
        self.lost = False
        self.counts: Counter = Counter()  # polls, answers, timeouts, bad frames ..., disconnects, connect failures

    # -- lifecycle ----------------------------------------------------------------------------------
    def open(self) -> bool:
        """Connect and send the first request now (before the app joins: the request then enters the
        controller at the run's first step). False when the port cannot be opened (the thread retries)."""
        with self._lock:
            ok = self._connect_locked()
            if ok:
                self._send_locked()
        return ok

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="controller-link", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        with self._lock:
            self._close_port_locked()

    def follow(self, clock) -> None:
        """Measure the answer timeout on `clock` (a callable returning seconds; NaN while it has no time yet,
        which never times out) in place of wall time: in lockstep, the app's simulation time."""
        with self._lock:
            self._clock = clock
            if self._outstanding_since is not None:
                self._outstanding_since = float("nan")  # dated again at the clock's first reading

    def stats(self) -> dict:
        with self._lock:
            return {"url": self.url, "connected": self._port is not None, "lost": self.lost, **dict(self.counts)}

    # -- the app's side ------------------------------------------------------------------------------
    def collect(self) -> list[StatusAnswer]:
        """Completed answers since the last call (reading what has arrived first)."""
        with self._lock:
            self._pump_locked()
            out, self._answers = self._answers, []
        return out

    def set_preempt(self, on: bool) -> None:
        """Ask for (True) or release (False) the controller's emergency-vehicle preemption: the SetPreempt frame
        goes out in place of the next poll (right away when nothing is in flight)."""
        with self._lock:
            self._preempt_wanted = bool(on)
            if self._port is not None and self._outstanding_since is None:
                self._send_locked()

    def collect_preempt(self) -> list[PreemptAck]:
        """SetPreempt acknowledgements read by `collect()` (call it first, at the same tick) since the last call."""
        with self._lock:
            out, self._preempt_acks = self._preempt_acks, []
        return out

    # -- internals ------------------------------------------------------------------------------------
    def _connect_locked(self) -> bool:
        try:
            if self._opener is not None:
                port = self._opener(self.url)
            else:
                import serial

                port = serial.serial_for_url(self.url, baudrate=self.baud, bytesize=8, parity="N", stopbits=1,
                                             timeout=0)
        except Exception as exc:  # pyserial raises SerialException, ValueError, OSError...
            self.counts["connect_failures"] += 1
            (log.warning if self.counts["connect_failures"] == 1 else log.debug)(
                "controller link %s: cannot open: %s (retrying every %g s)", self.url, exc, RECONNECT_S)
            return False
        self._port = port
        self._decoder = ab3418.FrameDecoder()
        self._outstanding_since = None
        if self._preempt_in_flight is not None and self._preempt_wanted is None:
            self._preempt_wanted = self._preempt_in_flight[0]  # lost with the old connection: send it again
        self._preempt_in_flight = None
        self.counts["connects"] += 1
        return True

    def _close_port_locked(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except Exception as exc:  # closing a dead port
                log.debug("controller link: closing: %s", exc)
        self._port = None
        self._outstanding_since = None

    def _send_locked(self) -> None:
        if self._port is None or self._stop.is_set():
            return
        frame, preempt = self.request, None
        if self._preempt_wanted is not None:
            preempt = self._preempt_wanted
            frame = ab3418.request(ab3418.SET_PREEMPT, self.station, bytes([0x01 if preempt else 0x00]))
        try:
            self._port.write(frame)
        except Exception as exc:
            self._disconnected_locked(f"write failed: {exc}")
            return
        self._outstanding_since = self._clock()
        if preempt is None:
            self.counts["polls"] += 1
        else:
            self._preempt_wanted = None
            self._preempt_in_flight = (preempt, len(frame))
            self.counts["preempt_requests"] += 1

    def _disconnected_locked(self, why: str) -> None:
        self.counts["disconnects"] += 1
        log.warning("controller link %s: %s; reconnecting", self.url, why)
        self._close_port_locked()

    def _pump_locked(self) -> None:
        port = self._port
        if port is None:
            return
        try:
            data = port.read(4096)
        except Exception as exc:  # SerialException('socket disconnected'), OSError
            self._disconnected_locked(f"read failed: {exc}")
            return
        if not data:
            return
        for event in self._decoder.feed(data):
            if isinstance(event, ab3418.FrameError):
                self.counts[f"bad_frame_{event.kind}"] += 1
                (log.warning if self.counts[f"bad_frame_{event.kind}"] == 1 else log.debug)(
                    "controller link: bad frame (%s): %s", event.kind, event.raw[:24].hex())
                continue
            self._on_frame_locked(event)

    def _on_frame_locked(self, frame: ab3418.Frame) -> None:
        if self._preempt_in_flight is not None and frame.station == self.station and frame.msg_type in (
                ab3418.response_type(ab3418.SET_PREEMPT), ab3418.error_type(ab3418.SET_PREEMPT)):
            on, n_req = self._preempt_in_flight
            ok = frame.msg_type == ab3418.response_type(ab3418.SET_PREEMPT)
            self.counts["preempt_acks" if ok else "preempt_errors"] += 1
            if not ok:
                log.warning("controller link: the controller refused SetPreempt(%s): %s", on, frame.data.hex())
            self._preempt_acks.append(PreemptAck(on, n_req, len(frame.encode()), ok, time.monotonic()))
            self._preempt_in_flight = None
            self._answered_locked()
            return
        if frame.msg_type == ab3418.error_type(self.request_type):
            self.counts["error_answers"] += 1
            log.warning("controller link: the controller answered with an error: %s", frame.data.hex())
            self._answered_locked()
            return
        if frame.msg_type != self.answer_type or frame.station != self.station:
            self.counts["unexpected_frames"] += 1
            log.debug("controller link: unexpected frame type %#x from station %d", frame.msg_type, frame.station)
            return
        try:
            status = (ab3418.LongStatus8 if self.request_type == ab3418.GET_LONG_STATUS8
                      else ab3418.ShortStatus).decode(frame.data)
        except ValueError as exc:
            self.counts["bad_answers"] += 1
            log.warning("controller link: unusable status answer: %s", exc)
            self._answered_locked()
            return
        self.counts["answers"] += 1
        self._answers.append(StatusAnswer(status, len(frame.encode()), time.monotonic()))
        self._answered_locked()

    def _answered_locked(self) -> None:
        if self.lost:
            log.warning("controller link %s: the controller answers again", self.url)
        self.lost = False
        self._consecutive_timeouts = 0
        self._outstanding_since = None
        self._send_locked()  # back to back: the next request at once

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                port = self._port
            if port is None:
                with self._lock:
                    if self._connect_locked():
                        self._send_locked()
                if self._port is None:
                    self._stop.wait(RECONNECT_S)
                continue
            try:
                fd = port.fileno()
                select.select([fd], [], [], 0.05)
            except (OSError, ValueError, AttributeError):
                self._stop.wait(0.01)  # a port without a file descriptor: poll
            with self._lock:
                if self._port is not port:
                    continue
                self._pump_locked()
                since, now = self._outstanding_since, self._clock()
                if since is not None and since != since and now == now:  # sent before the clock had a time
                    self._outstanding_since = since = now
                if self._port is not None and (since is None or now - since > self.answer_timeout_s):
                    if since is not None:
                        self.counts["timeouts"] += 1
                        self._consecutive_timeouts += 1
                        if self._consecutive_timeouts >= LOST_AFTER and not self.lost:
                            self.lost = True
                            log.warning("controller link %s: no answer to %d polls in a row: controller lost",
                                        self.url, self._consecutive_timeouts)
                    self._send_locked()
