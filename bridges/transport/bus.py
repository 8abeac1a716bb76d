"""Bus and Subscription: what every backend shares, so backends only move bytes.

A backend subclasses :class:`Bus` and implements ``_send`` (put envelope bytes on the wire), and where
it needs them ``_declare``/``_undeclare`` (per-subscription set-up) and ``_close``. Whatever it reads
from the wire it hands to :meth:`Bus._on_envelope`, which decodes, checks version, prefix, size,
duplicates and order, counts every rejection with its reason, and delivers to subscriptions.
Nothing read from the network raises out of it.
"""
from __future__ import annotations

import collections
import logging
import secrets
import threading
import time
from typing import Callable

from bridges.transport.envelope import (DEFAULT_MAX_SIZE, Message, as_buffer, decode, encode, encoded_size,
                                        validate_sender)
from bridges.transport.errors import EnvelopeError, TransportError, VersionMismatch
from bridges.transport.keys import join, matches, relative, validate_expr, validate_key

__all__ = ["Bus", "Subscription", "COUNTERS"]

log = logging.getLogger("bridges.transport")

COUNTERS = (
    "published",           # messages this bus sent
    "received",            # deliveries to subscriptions (one message matching two subscriptions: 2)
    "garbage",             # bytes that are not an envelope / fragment (reason logged)
    "truncated",           # envelopes that end inside a field
    "oversized",           # received messages over max_size
    "version_mismatch",    # envelopes of another major protocol version (dropped)
    "duplicates",          # (sender, key, seq) seen before by that subscription: dropped
    "reordered",           # seq lower than the last seen: delivered
    "dropped_queue_full",  # oldest message pushed out of a full subscription queue
    "superseded",          # latest_only: an unread message replaced by a newer one
    "other_prefix",        # envelopes of another run (prefix) heard on a shared wire: ignored
    "callback_errors",     # exceptions raised by subscription callbacks (logged)
    "send_errors",         # datagrams/puts the backend could not send
    "incomplete",          # fragmented messages that never completed (UDP)
)

_WINDOW = 1024  # how far back duplicates are recognised, in seq numbers per stream


class _SeqWindow:
    """Highest seq seen on one stream and a bitmap of the _WINDOW before it (anti-replay style)."""

    __slots__ = ("hi", "mask")

    def __init__(self) -> None:
        self.hi = -1
        self.mask = 0

    def check(self, seq: int) -> str:
        """'new', 'duplicate' or 'reordered' (and remember seq)."""
        if seq > self.hi:
            shift = seq - self.hi
            self.mask = ((self.mask << shift) | 1) & ((1 << _WINDOW) - 1) if shift < _WINDOW else 1
            self.hi = seq
            return "new"
        back = self.hi - seq
        if back >= _WINDOW:
            return "reordered"  # too old to tell: deliver
        bit = 1 << back
        if self.mask & bit:
            return "duplicate"
        self.mask |= bit
        return "reordered"


class Subscription:
    """Messages on one key expression: a bounded queue read with `recv`, or a callback.

    Callbacks run on the backend's receive thread: keep them short (hand work to a queue).
    """

    def __init__(self, bus: "Bus", key_expr: str, callback: Callable[[Message], object] | None,
                 latest_only: bool, maxlen: int):
        if maxlen < 1:
            raise TransportError(f"maxlen must be >= 1, got {maxlen}")
        self.bus = bus
        self.key_expr = key_expr                   # relative to the bus prefix, canonical
        self.full_expr = join(bus.prefix, key_expr)
        self.callback = callback
        self.latest_only = latest_only
        self._queue: collections.deque[Message] = collections.deque(maxlen=1 if latest_only else maxlen)
        self._cond = threading.Condition()
        self._streams: dict[tuple[str, int, str], _SeqWindow] = {}
        self.closed = False
        self.backend_handle: object = None         # whatever the backend keeps per subscription

    def matches(self, key: str) -> bool:
        return matches(self.key_expr, key)

    def _track(self, msg: Message) -> str:
        stream = (msg.sender, msg.session, msg.key)
        window = self._streams.get(stream)
        if window is None:
            window = self._streams[stream] = _SeqWindow()
        return window.check(msg.seq)

    def _offer(self, msg: Message) -> None:
        if self.callback is not None:
            try:
                self.callback(msg)
            except Exception:  # a bad callback must not kill the receive thread
                self.bus._count("callback_errors")
                log.exception("subscription %r: callback raised on %s from %s", self.key_expr, msg.key, msg.sender)
            return
        with self._cond:
            if len(self._queue) == self._queue.maxlen:
                self.bus._count("superseded" if self.latest_only else "dropped_queue_full")
            self._queue.append(msg)
            self._cond.notify()

    def recv(self, timeout: float | None = None) -> Message | None:
        """The oldest queued message (the newest with latest_only); None on timeout or once closed."""
        if self.callback is not None:
            raise TransportError(f"subscription {self.key_expr!r} has a callback; recv is not used")
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._queue:
                if self.closed:
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return self._queue.popleft()

    def pending(self) -> int:
        return len(self._queue)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.bus._remove(self)
        with self._cond:
            self._cond.notify_all()

    def __enter__(self) -> "Subscription":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<Subscription {self.full_expr!r} on {self.bus.backend}{' closed' if self.closed else ''}>"


class Bus:
    """One participant's connection to the run: publish envelopes, subscribe to key expressions."""

    backend = "abstract"

    def __init__(self, *, prefix: str, sender: str, max_size: int = DEFAULT_MAX_SIZE):
        self.prefix = validate_key(prefix, "prefix")
        self.sender = validate_sender(sender)
        if max_size < 64:
            raise TransportError(f"max_size {max_size} is too small for an envelope")
        self.max_size = int(max_size)
        self.session = secrets.randbits(32) or 1
        self._lock = threading.Lock()
        self._seq: dict[str, int] = {}
        self._subs: list[Subscription] = []
        self._counts = dict.fromkeys(COUNTERS, 0)
        self._streams: dict[tuple[str, str], dict[str, int]] = {}
        self._warned: set = set()
        self.closed = False

    # -- API ------------------------------------------------------------------------------
    def publish(self, key: str, payload: bytes | bytearray | memoryview, t_sim: float,
                stamps: dict[str, int] | None = None) -> int:
        """Send `payload` on `key` (relative to the prefix); returns its per-key seq (from 0)."""
        self._check_open()
        validate_key(key)
        full = join(self.prefix, key)
        try:
            payload = as_buffer(payload)
        except ValueError as exc:
            raise TransportError(f"cannot publish on {key!r}: {exc}") from None
        n = len(payload)
        size = encoded_size(self.sender, full, n, stamps)
        if size > self.max_size:
            raise TransportError(f"message on {key!r} would be {size} bytes (payload {n}), over this bus's "
                                 f"limit of {self.max_size} bytes (max_size)")
        with self._lock:
            seq = self._seq.get(key, 0)
            self._seq[key] = seq + 1
        try:
            data = encode(self.sender, full, t_sim, seq, payload, stamps, session=self.session)
        except (ValueError, TypeError) as exc:
            raise TransportError(f"cannot publish on {key!r}: {exc}") from None
        self._send(full, data)
        self._count("published")
        return seq

    def subscribe(self, key_expr: str, callback: Callable[[Message], object] | None = None, *,
                  latest_only: bool = False, maxlen: int = 1024) -> Subscription:
        self._check_open()
        sub = Subscription(self, validate_expr(key_expr), callback, latest_only, maxlen)
        self._declare(sub)
        with self._lock:
            self._subs.append(sub)
        return sub

    def stats(self) -> dict:
        """Counters (see COUNTERS) plus the backend name."""
        with self._lock:
            return {"backend": self.backend, **self._counts}

    def stream_stats(self) -> dict[tuple[str, str], dict[str, int]]:
        """Per (sender, key): received, duplicates, reordered, last_seq."""
        with self._lock:
            return {k: dict(v) for k, v in self._streams.items()}

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for sub in list(self._subs):
            sub.close()
        self._close()

    def __enter__(self) -> "Bus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.prefix!r} as {self.sender!r}{' closed' if self.closed else ''}>"

    # -- for backends -------------------------------------------------------------------
    def _send(self, full_key: str, data: bytes) -> None:
        raise NotImplementedError

    def _declare(self, sub: Subscription) -> None:
        """Backend set-up for a new subscription (zenoh: declare a subscriber)."""

    def _undeclare(self, sub: Subscription) -> None:
        """Backend tear-down of a subscription."""

    def _close(self) -> None:
        """Backend tear-down of the bus (sockets, sessions, threads)."""

    def _check_open(self) -> None:
        if self.closed:
            raise TransportError(f"{self!r} is closed")

    def _remove(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)
        try:
            self._undeclare(sub)
        except Exception as exc:  # closing must not fail because the peer is gone
            log.debug("undeclaring %r: %s", sub, exc)

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._counts[name] += n

    def _warn_once(self, token: object, text: str, *args) -> None:
        """Log at WARNING the first time for `token`, at DEBUG after (a flood must not flood the log)."""
        level = logging.DEBUG
        with self._lock:
            if token not in self._warned and len(self._warned) < 10_000:
                self._warned.add(token)
                level = logging.WARNING
        log.log(level, text, *args)

    def _on_envelope(self, data: bytes | memoryview, *, subs: list[Subscription] | None = None,
                     wire_key: str | None = None, source: object = None,
                     received_ns: int | None = None) -> None:
        """Decode and deliver bytes read from the wire. Never raises: every rejection is counted.

        `subs`: deliver only to these (a backend that matches keys itself, like Zenoh); default: every
        subscription of this bus whose expression matches. `wire_key`: the key the transport carried
        it on, which must equal the envelope's. `source`: where it came from, for the log.
        """
        try:
            if received_ns is None:
                received_ns = time.time_ns()
            size = data.nbytes if isinstance(data, memoryview) else len(data)
            if size > self.max_size:
                self._count("oversized")
                self._warn_once(("oversized", source), "%s: dropped a %d-byte message from %s: over max_size %d",
                                self.backend, size, source, self.max_size)
                return
            try:
                msg = decode(data, received_ns=received_ns)
            except VersionMismatch as exc:
                self._count("version_mismatch")
                self._warn_once(("version", exc.sender, exc.version), "%s: dropped: %s", self.backend, exc.reason)
                return
            except EnvelopeError as exc:
                self._count("truncated" if exc.kind == "truncated" else "garbage")
                self._warn_once((exc.kind, source), "%s: dropped bad envelope from %s: %s", self.backend,
                                source if source is not None else wire_key, exc.reason)
                return
            if wire_key is not None and wire_key != msg.key:
                self._count("garbage")
                self._warn_once(("wirekey", source), "%s: dropped envelope for %r carried on %r", self.backend,
                                msg.key, wire_key)
                return
            rel = relative(self.prefix, msg.key)
            if rel is None:
                self._count("other_prefix")
                return
            msg.key = rel
            if source is not None:
                msg.extra["source"] = source
            if subs is None:
                with self._lock:
                    subs = [s for s in self._subs if s.matches(rel)]
            for sub in subs:
                if sub.closed:
                    continue
                verdict = sub._track(msg)
                with self._lock:
                    stream = self._streams.get((msg.sender, rel))
                    if stream is None:
                        stream = self._streams[(msg.sender, rel)] = {"received": 0, "duplicates": 0,
                                                                      "reordered": 0, "last_seq": -1}
                    if verdict == "duplicate":
                        self._counts["duplicates"] += 1
                        stream["duplicates"] += 1
                        continue
                    if verdict == "reordered":
                        self._counts["reordered"] += 1
                        stream["reordered"] += 1
                    self._counts["received"] += 1
                    stream["received"] += 1
                    stream["last_seq"] = max(stream["last_seq"], msg.seq)
                sub._offer(msg)
        except Exception:  # last line of defence: a receive thread must survive anything
            self._count("garbage")
            log.exception("%s: unexpected error handling a message from %s", self.backend, source)

