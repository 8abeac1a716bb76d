"""Splitting envelopes into datagrams and putting them back together (the UDP backend's framing).

A raw 640x480x3 camera frame is 921,600 bytes; one datagram that fits an Ethernet frame carries
about 1.4 kB. Every datagram starts with::

    magic b"V2IF" | session u32 | msg_id u32 | offset u32 | total u32     (little-endian, 20 bytes)

`session` is the sending bus's random number (so a receiver can tell its own datagrams and a restarted
sender apart), `msg_id` numbers its messages, `offset`/`total` place the chunk in the envelope.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field

__all__ = ["HEADER", "MAGIC", "FragmentError", "split", "parse", "Reassembler"]

MAGIC = b"V2IF"
HEADER = struct.Struct("<4sIIII")


class FragmentError(ValueError):
    """A datagram that is not a fragment this side can use; `kind` is 'garbage' or 'oversized'."""

    def __init__(self, reason: str, kind: str = "garbage"):
        super().__init__(reason)
        self.reason = reason
        self.kind = kind


def split(data: bytes, session: int, msg_id: int, datagram_size: int) -> list[bytes]:
    """The datagrams carrying `data`, each at most `datagram_size` bytes."""
    chunk = datagram_size - HEADER.size
    if chunk <= 0:
        raise ValueError(f"datagram_size {datagram_size} leaves no room after the {HEADER.size}-byte header")
    total = len(data)
    view = memoryview(data)
    return [HEADER.pack(MAGIC, session, msg_id, off, total) + view[off:off + chunk]
            for off in range(0, max(total, 1), chunk)]


def parse(datagram: bytes) -> tuple[int, int, int, int, memoryview]:
    """(session, msg_id, offset, total, chunk) of one datagram; FragmentError if it is not one."""
    if len(datagram) < HEADER.size:
        raise FragmentError(f"datagram of {len(datagram)} bytes is shorter than the {HEADER.size}-byte "
                            f"fragment header")
    magic, session, msg_id, offset, total = HEADER.unpack_from(datagram)
    if magic != MAGIC:
        raise FragmentError(f"bad fragment magic {magic!r} (expected {MAGIC!r})")
    chunk = memoryview(datagram)[HEADER.size:]
    if offset + len(chunk) > total:
        raise FragmentError(f"fragment at offset {offset} with {len(chunk)} bytes overruns the declared "
                            f"total of {total}")
    if not chunk and total:
        raise FragmentError("empty fragment of a non-empty message")
    return session, msg_id, offset, total, chunk


def _remember(recent: dict, ident: tuple, keep: int = 256) -> None:
    recent[ident] = None
    if len(recent) > keep:
        del recent[next(iter(recent))]


@dataclass
class _Partial:
    total: int
    started: float
    buf: bytearray = field(init=False)
    offsets: set = field(default_factory=set)
    have: int = 0

    def __post_init__(self) -> None:
        self.buf = bytearray(self.total)


class Reassembler:
    """Collects fragments per (source, session, msg_id); gives back each complete message once.

    Incomplete messages are dropped after `timeout` seconds or when more than `max_pending` are open
    at once (oldest first); `expire` and `add` report how many were dropped so the bus can count them.
    """

    def __init__(self, max_size: int, timeout: float = 1.0, max_pending: int = 64):
        self.max_size = max_size
        self.timeout = timeout
        self.max_pending = max_pending
        self._open: dict[tuple, _Partial] = {}
        self._refused: dict[tuple, None] = {}  # oversized messages: ignore their other fragments quietly
        self._done: dict[tuple, None] = {}     # recently completed: a late duplicate must not reopen them
        self.dropped = 0  # incomplete messages given up, since the last `take_dropped`

    def add(self, datagram: bytes, source: object, now: float) -> bytes | memoryview | None:
        """The complete envelope once its last fragment arrives, else None. FragmentError on bad input."""
        session, msg_id, offset, total, chunk = parse(datagram)
        if offset == 0 and len(chunk) == total:
            if total > self.max_size:
                raise FragmentError(f"message of {total} bytes is over max_size {self.max_size}", "oversized")
            return chunk  # fits one datagram: no state
        ident = (source, session, msg_id)
        partial = self._open.get(ident)
        if partial is None:
            if ident in self._refused or ident in self._done:
                return None
            if total > self.max_size:
                _remember(self._refused, ident)
                raise FragmentError(f"message of {total} bytes is over max_size {self.max_size}", "oversized")
            if len(self._open) >= self.max_pending:
                del self._open[next(iter(self._open))]
                self.dropped += 1
            partial = self._open[ident] = _Partial(total, now)
        elif partial.total != total:
            raise FragmentError(f"fragment says total {total}, earlier fragments of message {msg_id} said "
                                f"{partial.total}")
        if offset in partial.offsets:
            return None  # a duplicated datagram
        partial.offsets.add(offset)
        partial.buf[offset:offset + len(chunk)] = chunk
        partial.have += len(chunk)
        if partial.have >= total:
            del self._open[ident]
            _remember(self._done, ident)
            return partial.buf
        return None

    def expire(self, now: float) -> int:
        """Drop messages older than the timeout; returns how many."""
        stale = [k for k, p in self._open.items() if now - p.started > self.timeout]
        for k in stale:
            del self._open[k]
        self.dropped += len(stale)
        return len(stale)

    def take_dropped(self) -> int:
        n, self.dropped = self.dropped, 0
        return n

    @property
    def pending(self) -> int:
        return len(self._open)
