"""SAE J2735 messages in UPER: the codec, typed messages in SI units, the JSON form."""
from bridges.j2735.codec import (MESSAGE_IDS, MESSAGE_TYPES, Frame, J2735Codec, J2735Error,
                                 default_codec)

__all__ = ["MESSAGE_IDS", "MESSAGE_TYPES", "Frame", "J2735Codec", "J2735Error", "default_codec"]
