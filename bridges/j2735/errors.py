"""The one error of the J2735 package (codec, typed messages, editions, ASN.1 loading)."""
from __future__ import annotations


class J2735Error(ValueError):
    """A message that cannot be decoded or encoded, or a codec that cannot be built; `reason` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason
