"""What the typed messages share: the MessageFrame around them, and the untyped rest kept on the way through.

Every typed message (BSM, MAP, SPaT, SRM, SSM, SDSM) had the same four
methods written out again; they live here once:

* `Kept` is a typed value whose asn1tools form is its `_typed(...)` plus what
  the typed fields do not model, kept in `other` (bridges.j2735.fields):
  `to_asn1(...)` puts the kept rest back, `_keep(received)` records it when
  decoding. `_typed`'s arguments (where, for error messages) pass through.
* `Framed` is a message with a messageId: `encode(codec)` gives the UPER
  MessageFrame, `decode(data, codec)` reads one and refuses a frame that holds
  another message, or one whose type the codec's ASN.1 lacks (a user's
  licensed files of an edition without it). A message whose values depend on
  the codec's edition (the BSM's SSP member, SPaT's time marks) overrides
  `_to_wire`/`_from_wire` to pass it.
"""
from __future__ import annotations

from typing import Any

from bridges.j2735 import fields as f
from bridges.j2735.codec import MESSAGE_TYPES, J2735Codec, J2735Error, default_codec


class Kept:
    """A typed value that keeps what it does not model in `other` (a dataclass field of the subclass)."""

    other: dict[str, Any] | None

    def _typed(self, *args: Any) -> dict[str, Any]:
        raise NotImplementedError

    def to_asn1(self, *args: Any) -> dict[str, Any]:
        """asn1tools values: the typed fields, plus the kept rest where they have nothing."""
        return f.fill(self._typed(*args), self.other)

    def _keep(self, received: dict[str, Any]):
        """Record in `other` what `received` holds beyond the typed fields; returns self."""
        self.other = f.residue(received, self._typed())
        return self


class Framed:
    """A top-level message: `MESSAGE_ID` (DSRCmsgID) and `WHAT` ("an SRM") name it in errors."""

    MESSAGE_ID: int
    WHAT: str

    def _to_wire(self, codec: J2735Codec) -> dict[str, Any]:
        return self.to_asn1()

    @classmethod
    def _from_wire(cls, message: dict[str, Any], codec: J2735Codec):
        return cls.from_asn1(message)

    def encode(self, codec: J2735Codec | None = None) -> bytes:
        """The UPER MessageFrame; J2735Error naming the field for a value the message cannot carry."""
        codec = codec or default_codec()
        return codec.encode(self.MESSAGE_ID, self._to_wire(codec))

    @classmethod
    def decode(cls, data: bytes, codec: J2735Codec | None = None):
        """The typed message of a MessageFrame; J2735Error when the bytes are no such message."""
        codec = codec or default_codec()
        frame = codec.decode(data)
        if frame.message_id != cls.MESSAGE_ID:
            raise J2735Error(f"messageId {frame.message_id} is not {cls.WHAT} ({cls.MESSAGE_ID})")
        if frame.message is None:
            raise J2735Error(f"messageId {frame.message_id} ({MESSAGE_TYPES.get(cls.MESSAGE_ID)}): the codec's "
                             f"ASN.1 {[p.name for p in codec.sources]} has no such type")
        return cls._from_wire(frame.message, codec)
