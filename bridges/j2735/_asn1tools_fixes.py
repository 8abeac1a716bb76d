"""Extensible BIT STRING sizes in asn1tools' UPER codec (X.691 §16.6).

asn1tools 0.169 raises NotImplementedError for a BIT STRING whose size lies
outside an extensible size constraint, e.g. `LaneAttributes-Vehicle ::=
BIT STRING (SIZE(8, ...))`. Deployed encoders emit exactly that: the
carma-messenger MAP in the interop vectors sends a zero-length vehicle
attribute (extension bit 1, length 0). X.691 encodes such a value with the
extension bit set and then as if unconstrained: a length determinant and the
bits. `apply()` adds that case, leaving every in-root value to asn1tools.
"""
from __future__ import annotations

from asn1tools.codecs import uper

_applied = False


def _encode(self, data, encoder):
    value, number_of_bits = data
    if self.has_extension_marker and not (self.minimum <= number_of_bits <= self.maximum):
        encoder.append_bit(1)
        self.encode_unbound(value, number_of_bits, encoder)
        return
    _root_encode(self, data, encoder)


def _decode(self, decoder):
    # Same as asn1tools' root decoding, plus the extension case.
    if self.has_extension_marker and decoder.read_bit():
        return self.decode_unbound(decoder)
    if self.number_of_bits is None:
        return self.decode_unbound(decoder)
    number_of_bits = self.minimum
    if self.minimum != self.maximum:
        number_of_bits += decoder.read_non_negative_binary_integer(self.number_of_bits)
    return (decoder.read_bits(number_of_bits), number_of_bits)


_root_encode = uper.BitString.encode


def apply() -> None:
    global _applied
    if not _applied:
        uper.BitString.encode = _encode
        uper.BitString.decode = _decode
        _applied = True
