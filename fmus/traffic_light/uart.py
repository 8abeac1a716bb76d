"""UART timing: each byte occupies the line for one character time, start to stop bit.

A character is 1 start bit, the data bits, an optional parity bit and the stop
bits: at 8N1 it is 10 bit times, 1.0417 ms at 9600 baud (ANCHORS S1). A byte is
available to the receiver when its stop bit has been sent, so n bytes written at
once arrive after n character times (1024 bytes at 9600 8N1: 1066.67 ms, S2).

:class:`Wire` is one direction of the line. Bytes handed to it queue behind the
bytes still on the line (the sender's transmit buffer); while the line stays busy
their arrival times are computed from the start of the burst, so long transfers
carry no accumulated rounding.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

PARITIES = ("N", "E", "O", "M", "S")  # as pyserial names them
_EPS = 1e-9


@dataclass(frozen=True)
class UartConfig:
    baud: float = 9600.0
    data_bits: int = 8
    parity: str = "N"
    stop_bits: float = 1.0

    def validate(self) -> None:
        if isinstance(self.baud, bool) or not isinstance(self.baud, (int, float)) or not 50 <= self.baud <= 10_000_000:
            raise ValueError(f"baud = {self.baud!r}: must be 50..10000000 bit/s")
        if self.data_bits not in (5, 6, 7, 8):
            raise ValueError(f"data_bits = {self.data_bits!r}: must be 5, 6, 7 or 8")
        if self.parity not in PARITIES:
            raise ValueError(f"parity = {self.parity!r}: must be one of {', '.join(PARITIES)} (pyserial's names)")
        if self.stop_bits not in (1, 1.5, 2):
            raise ValueError(f"stop_bits = {self.stop_bits!r}: must be 1, 1.5 or 2")

    @property
    def bits_per_char(self) -> float:
        return 1 + self.data_bits + (0 if self.parity == "N" else 1) + self.stop_bits

    @property
    def char_time(self) -> float:
        """Seconds one byte occupies the line (ANCHORS S1: 10 / baud at 8N1)."""
        return self.bits_per_char / self.baud

    @property
    def mask(self) -> int:
        """Bits of a byte that survive the line (fewer than 8 data bits drop the high ones)."""
        return (1 << self.data_bits) - 1


class Wire:
    """One direction of a serial line: bytes in at a time, out after their character time."""

    def __init__(self, config: UartConfig, capacity: int | None = None):
        self.char_time = config.char_time
        self.mask = config.mask
        self.capacity = capacity  # bytes that may wait (sender's buffer); None = unbounded
        self._queue: deque[tuple[float, int]] = deque()
        self._burst_start = -float("inf")
        self._burst_n = 0
        self.free_at = -float("inf")  # when the last queued byte is off the line

    def send(self, data: bytes, t: float) -> int:
        """Queue `data` written at time `t`; returns how many bytes were accepted."""
        accepted = 0
        for b in data:
            if self.capacity is not None and len(self._queue) >= self.capacity:
                break
            if self.free_at <= t + _EPS:  # line idle: a new burst starts now
                self._burst_start, self._burst_n = t, 0
            self._burst_n += 1
            done = self._burst_start + self._burst_n * self.char_time
            self.free_at = done
            self._queue.append((done, b & self.mask))
            accepted += 1
        return accepted

    def next_time(self) -> float:
        return self._queue[0][0] if self._queue else float("inf")

    def pop(self) -> tuple[float, int]:
        return self._queue.popleft()

    def pop_until(self, t: float) -> list[tuple[float, int]]:
        out = []
        q = self._queue
        while q and q[0][0] <= t + _EPS:
            out.append(q.popleft())
        return out

    def busy(self, t: float) -> bool:
        return self.free_at > t + _EPS

    def __len__(self) -> int:
        return len(self._queue)
