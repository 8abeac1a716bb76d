"""The controller's end of the AB3418-like link: requests in, answers out, bad input counted.

What the controller answers (AB3418 is a poll / response protocol):

* GetShortStatus (0x84) -> 0xC4; GetLongStatus8 (0x8C) -> 0xCC; SetPreempt (0x9B,
  this project's) -> 0xDB, the call taking effect when the request has arrived;
* a request type it does not know (0x80-0x9F) -> error answer ``type | 0x60`` with
  ERR_NO_SUCH_NAME; a known request with the wrong data length -> ERR_MESS_LEN; a
  value it cannot act on (a preempt other than A) -> ERR_BAD_VALUE, index = byte;
* frames for another station, broadcasts (acted on, never answered) and non-request
  types are not answered;
* garbage, truncated frames, FCS errors and oversize frames are dropped silently;
* a request arriving while `max_pending` requests are still being answered (a flood
  faster than the line can carry the answers) is dropped.

Every case is counted by kind in :attr:`ControllerEndpoint.counters`. An answer starts
`turnaround` after its request arrived (AB3418 T2, default 10 ms), or when the line
is free, and carries the controller state at that instant.
"""
from __future__ import annotations

from collections import deque
from typing import Callable

try:  # inside the built FMU: the private copy of bridges/ab3418.py (fmus/builder.py)
    from fmus._bundled import ab3418
except ImportError:  # working tree
    from bridges import ab3418

COUNTERS = ("frames_ok", "frames_ignored", "responses_sent", "err_fcs", "err_truncated", "err_garbage",
            "err_oversize", "err_unknown_type", "err_bad_request", "err_overrun", "err_rx_overflow")
_KIND_COUNTER = {ab3418.FCS: "err_fcs", ab3418.TRUNCATED: "err_truncated", ab3418.GARBAGE: "err_garbage",
                 ab3418.OVERSIZE: "err_oversize"}
_EPS = 1e-9


class ControllerEndpoint:
    """Decodes received bytes, schedules and builds answers.

    `status(kind, t)` returns the data bytes of a status answer at time t (kind is the
    request type); `set_preempt(on)` latches the serial preemption call.
    """

    def __init__(self, station: int, status: Callable[[int], bytes], set_preempt: Callable[[bool], None],
                 line_free_at: Callable[[], float], turnaround: float = 0.010, max_pending: int = 1,
                 fcs_order: str = ab3418.LSB_FIRST, max_frame: int = ab3418.MAX_FRAME):
        self.station = station
        self.address = ab3418.station_address(station)
        self.status = status
        self.set_preempt = set_preempt
        self.line_free_at = line_free_at
        self.turnaround = turnaround
        self.max_pending = max_pending
        self.fcs_order = fcs_order
        self.decoder = ab3418.FrameDecoder(fcs_order=fcs_order, max_frame=max_frame)
        self.counters = {name: 0 for name in COUNTERS}
        self._queue: deque[tuple[float, int, bytes]] = deque()  # (ready time, answer type, data)
        self._answer_ends: deque[float] = deque()  # end times of answers on the line

    # -- receive -------------------------------------------------------------------
    def on_byte(self, b: int, t: float) -> None:
        event = self.decoder.feed_byte(b)
        if event is None:
            return
        if isinstance(event, ab3418.FrameError):
            self.counters[_KIND_COUNTER[event.kind]] += 1
            return
        self._on_frame(event, t)

    def _on_frame(self, frame: ab3418.Frame, t: float) -> None:
        if frame.station != self.station and not frame.broadcast:
            self.counters["frames_ignored"] += 1
            return
        self.counters["frames_ok"] += 1
        if not ab3418.is_request_type(frame.msg_type):  # an answer type: nothing to answer
            self.counters["err_unknown_type"] += 1
            return
        mt, data = frame.msg_type, frame.data
        expected = {ab3418.GET_SHORT_STATUS: 0, ab3418.GET_LONG_STATUS8: 0, ab3418.SET_PREEMPT: 1}.get(mt)
        if expected is None:
            self.counters["err_unknown_type"] += 1
            answer = (ab3418.error_type(mt), ab3418.ErrorResponse(ab3418.ERR_NO_SUCH_NAME, 0).encode())
        elif len(data) != expected:
            self.counters["err_bad_request"] += 1
            answer = (ab3418.error_type(mt), ab3418.ErrorResponse(ab3418.ERR_MESS_LEN, 0).encode())
        elif mt == ab3418.SET_PREEMPT:
            if data[0] & 0xFE:  # only preempt A (bit 0) is modelled
                self.counters["err_bad_request"] += 1
                answer = (ab3418.error_type(mt), ab3418.ErrorResponse(ab3418.ERR_BAD_VALUE, 1).encode())
            else:
                self.set_preempt(bool(data[0] & 0x01))
                answer = (ab3418.response_type(mt), b"")
        else:
            answer = (ab3418.response_type(mt), None)  # status: built when the answer starts
        if frame.broadcast:
            return
        self._schedule(t, *answer)

    def _schedule(self, t: float, msg_type: int, data: bytes | None) -> None:
        while self._answer_ends and self._answer_ends[0] <= t + _EPS:
            self._answer_ends.popleft()
        if len(self._queue) + len(self._answer_ends) >= self.max_pending:
            self.counters["err_overrun"] += 1
            return
        self._queue.append((t + self.turnaround, msg_type, data))

    # -- transmit -------------------------------------------------------------------
    def next_answer_time(self) -> float:
        if not self._queue:
            return float("inf")
        return max(self._queue[0][0], self.line_free_at())

    def pop_answer(self, t: float) -> bytes:
        """The next answer as a complete frame, built at time t (when it starts on the line)."""
        _, msg_type, data = self._queue.popleft()
        if data is None:
            data = self.status(msg_type & ~0x40)
        self.counters["responses_sent"] += 1
        return ab3418.encode_frame(self.station, msg_type, data, fcs_order=self.fcs_order)

    def answer_sent(self, end: float) -> None:
        """The last byte of the answer just queued leaves the line at `end`."""
        self._answer_ends.append(end)

    @property
    def busy(self) -> bool:
        return bool(self._queue)
