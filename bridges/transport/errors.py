"""The transport's exceptions, in one place so every backend raises the same ones."""
from __future__ import annotations

__all__ = ["TransportError", "KeyExprError", "EnvelopeError", "VersionMismatch"]


class TransportError(Exception):
    """Anything the transport refuses or cannot do; the message says what and why."""


class KeyExprError(TransportError, ValueError):
    """A key or key expression that no backend may carry; the message says which chunk and why."""


class EnvelopeError(TransportError, ValueError):
    """Bytes that are not a valid envelope.

    `kind` sorts the reason for the counters: ``"truncated"`` (the bytes end inside a field),
    ``"version"`` (see VersionMismatch) or ``"garbage"`` (anything else).
    """

    def __init__(self, reason: str, kind: str = "garbage"):
        super().__init__(reason)
        self.reason = reason
        self.kind = kind


class VersionMismatch(EnvelopeError):
    """An envelope of another major protocol version: readable only up to its sender."""

    def __init__(self, reason: str, version: tuple[int, int], sender: str | None):
        super().__init__(reason, "version")
        self.version = version
        self.sender = sender
