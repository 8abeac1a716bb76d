"""Envelope codec, key expressions, fragmentation and bookkeeping of the transport layer (no network)."""
from __future__ import annotations

import math
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bridges.transport import (PROTOCOL_VERSION, EnvelopeError, KeyExprError, TransportError, VersionMismatch,
                               decode, encode, open_bus)
from bridges.transport.bus import _SeqWindow
from bridges.transport.envelope import MAGIC, encoded_size
from bridges.transport.fragments import HEADER, FragmentError, Reassembler, split
from bridges.transport.keys import canonize, matches, validate_expr, validate_key

FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def sample(**kw) -> bytes:
    args = dict(sender="rsu1", key="v2i/run1/v2x/tx/rsu1", t_sim=12.5, seq=7, payload=b"\x00\x01payload",
                stamps={"detected": 1_700_000_000_000_000_000, "encoded": 1_700_000_000_000_500_000})
    args.update(kw)
    return encode(args.pop("sender"), args.pop("key"), args.pop("t_sim"), args.pop("seq"), args.pop("payload"),
                  args.pop("stamps"), **args)


# -- envelope ------------------------------------------------------------------------------
def test_round_trip_keeps_every_field():
    data = sample(session=99)
    msg = decode(data, received_ns=5)
    assert (msg.sender, msg.key, msg.t_sim, msg.seq, msg.payload) == \
        ("rsu1", "v2i/run1/v2x/tx/rsu1", 12.5, 7, b"\x00\x01payload")
    assert msg.stamps == {"detected": 1_700_000_000_000_000_000, "encoded": 1_700_000_000_000_500_000}
    assert msg.version == PROTOCOL_VERSION and msg.session == 99 and msg.received_ns == 5
    assert len(data) == encoded_size("rsu1", "v2i/run1/v2x/tx/rsu1", len(b"\x00\x01payload"), msg.stamps)


def test_envelope_is_compact():
    # fixed overhead: 4 magic + 2 version + 1 + sender + 30 fixed + key + 1 stamp count
    assert len(encode("a", "k", 0.0, 0, b"")) == 4 + 2 + 1 + 1 + 30 + 1 + 1


def test_every_truncation_names_its_field():
    data = sample()
    fields = set()
    for n in range(len(data)):
        with pytest.raises(EnvelopeError) as info:
            decode(data[:n])
        assert info.value.kind == "truncated", (n, info.value)
        assert str(info.value).startswith("truncated in ")
        fields.add(str(info.value).split(":")[0])
    assert {"truncated in magic", "truncated in sender", "truncated in fixed fields", "truncated in key",
            "truncated in payload"} <= fields


@pytest.mark.parametrize("mutate, reason", [
    (lambda d: b"XXXX" + d[4:], "bad magic"),
    (lambda d: d + b"extra", "length mismatch"),
    (lambda d: d[:7] + b"\xff" + d[8:], "bad UTF-8 in sender"),
])
def test_bad_envelopes_say_why(mutate, reason):
    with pytest.raises(EnvelopeError, match=reason) as info:
        decode(mutate(sample()))
    assert info.value.kind == "garbage"


def test_bad_utf8_in_key_and_stamp_name():
    data = bytearray(sample())
    key_at = data.index(b"v2i/run1")
    bad = bytes(data[:key_at]) + b"\xc3" + bytes(data[key_at + 1:])
    with pytest.raises(EnvelopeError, match="bad UTF-8 in key"):
        decode(bad)
    name_at = data.index(b"detected")
    bad = bytes(data[:name_at]) + b"\xff" + bytes(data[name_at + 1:])
    with pytest.raises(EnvelopeError, match="bad UTF-8 in stamp 0 name"):
        decode(bad)


def test_invalid_key_and_non_finite_time_on_the_wire_are_rejected():
    data = sample(key="v2i/run1/a#b")  # encode does not police key syntax, decode does
    with pytest.raises(EnvelopeError, match="reserved character '#'"):
        decode(data)
    data = bytearray(sample())
    t_at = 4 + 3 + len("rsu1") + 12
    assert struct.unpack_from("<d", data, t_at)[0] == 12.5
    struct.pack_into("<d", data, t_at, math.nan)
    with pytest.raises(EnvelopeError, match="t_sim is not finite"):
        decode(bytes(data))


def test_other_major_version_is_refused_with_both_versions_and_the_sender():
    data = sample(version=(2, 0))
    with pytest.raises(VersionMismatch) as info:
        decode(data)
    assert str(info.value) == "participant rsu1 speaks bridge protocol 2.0, this side 1.0"
    assert info.value.version == (2, 0) and info.value.sender == "rsu1" and info.value.kind == "version"


def test_newer_minor_with_header_extension_is_read_by_this_side():
    data = bytearray(sample(version=(1, 3)))
    head_at = 4 + 3 + len("rsu1")
    header_len, payload_len = struct.unpack_from("<II", data, head_at)
    extended = bytes(data[:header_len]) + b"EXT!" + bytes(data[header_len:])
    extended = bytearray(extended)
    struct.pack_into("<I", extended, head_at, header_len + 4)
    msg = decode(bytes(extended))
    assert msg.version == (1, 3) and msg.payload == b"\x00\x01payload" and msg.stamps["detected"]


@pytest.mark.parametrize("kwargs, error", [
    (dict(t_sim=math.inf), "t_sim must be finite"),
    (dict(seq=-1), "outside uint64"),
    (dict(stamps={"": 1}), "stamp name"),
    (dict(stamps={"x": 1 << 63}), "int64"),
    (dict(sender="a/b"), "single key chunk"),
])
def test_encode_refuses_what_it_cannot_carry(kwargs, error):
    with pytest.raises(ValueError, match=error):
        sample(**kwargs)


key_chunk = st.text(st.characters(blacklist_characters="/#?$*", blacklist_categories=("Cs", "Cc", "Zs", "Zl", "Zp",
                                                                                       "Cf", "Co", "Cn")),
                    min_size=1, max_size=8).filter(lambda c: c.isprintable() and not any(ch.isspace() for ch in c))
keys = st.lists(key_chunk, min_size=1, max_size=5).map("/".join)


@FUZZ
@given(sender=key_chunk, key=keys, t_sim=st.floats(allow_nan=False, allow_infinity=False),
       seq=st.integers(0, (1 << 64) - 1), session=st.integers(0, (1 << 32) - 1), payload=st.binary(max_size=300),
       stamps=st.dictionaries(st.text(min_size=1, max_size=10), st.integers(-(1 << 63), (1 << 63) - 1), max_size=5))
def test_round_trip_property(sender, key, t_sim, seq, session, payload, stamps):
    msg = decode(encode(sender, key, t_sim, seq, payload, stamps, session=session))
    assert (msg.sender, msg.key, msg.t_sim, msg.seq, msg.session, msg.payload, msg.stamps) == \
        (sender, key, t_sim, seq, session, payload, stamps)


@FUZZ
@given(st.binary(max_size=200))
def test_arbitrary_bytes_only_raise_envelope_error(data):
    try:
        decode(data)
    except EnvelopeError:
        pass


@FUZZ
@given(st.binary(max_size=120))
def test_arbitrary_bytes_after_the_magic_only_raise_envelope_error(data):
    try:
        decode(MAGIC + bytes([1, 0]) + data)
    except EnvelopeError:
        pass


@FUZZ
@given(st.data())
def test_mutated_envelopes_only_raise_envelope_error(data):
    raw = bytearray(sample())
    for _ in range(data.draw(st.integers(1, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    try:
        decode(bytes(raw))
    except EnvelopeError:
        pass


# -- keys ------------------------------------------------------------------------------
@pytest.mark.parametrize("key, reason", [
    ("", "empty"), ("/a", "leading"), ("a/", "trailing"), ("a//b", "chunk 1 is empty"),
    ("a/b#", "reserved character '#'"), ("a?b", r"'\?'"), ("$x", r"'\$'"), ("a b", "whitespace"),
    ("a/*", "reserved character '*'"),
])
def test_invalid_keys_say_why(key, reason):
    with pytest.raises(KeyExprError, match=reason):
        validate_key(key)


def test_expressions_allow_whole_chunk_wildcards_only():
    assert validate_expr("camera/*/frame") == "camera/*/frame"
    assert validate_expr("a/**/**/b") == "a/**/b"
    assert canonize(["**", "*"]) == ["*", "**"]
    with pytest.raises(KeyExprError, match="whole chunks"):
        validate_expr("cam*/x")


@pytest.mark.parametrize("expr, key, expected", [
    ("a/b", "a/b", True), ("a/b", "a/c", False), ("a/*", "a/b", True), ("a/*", "a/b/c", False),
    ("a/*", "a", False), ("a/**", "a", True), ("a/**", "a/b/c", True), ("**", "x", True),
    ("**/c", "a/b/c", True), ("**/c", "c", True), ("a/**/c", "a/c", True), ("a/**/c", "a/x/y/c", True),
    ("a/**/c", "a/x/y/d", False), ("*/b/**", "a/b", True), ("*", "a/b", False),
])
def test_wildcard_matching(expr, key, expected):
    assert matches(expr, key) is expected


# -- fragments -----------------------------------------------------------------------------
def test_fragments_reassemble_in_any_order_and_ignore_duplicates():
    data = bytes(range(256)) * 40  # 10240 bytes
    frags = split(data, 5, 9, 1000)
    assert len(frags) == math.ceil(len(data) / (1000 - HEADER.size)) and all(len(f) <= 1000 for f in frags)
    r = Reassembler(max_size=1 << 20)
    order = frags[::-1] + [frags[3]]
    out = [r.add(f, "peer", 0.0) for f in order]
    assert out.count(None) == len(order) - 1 and bytes(out[-2]) == data and out[-1] is None
    assert r.pending == 0


def test_single_datagram_message_needs_no_state():
    (frag,) = split(b"hello", 1, 1, 1400)
    r = Reassembler(max_size=100)
    assert bytes(r.add(frag, "p", 0.0)) == b"hello" and r.pending == 0


def test_incomplete_messages_time_out_and_are_counted():
    frags = split(bytes(5000), 1, 1, 1000)
    r = Reassembler(max_size=1 << 20, timeout=1.0)
    r.add(frags[0], "p", 0.0)
    assert r.expire(0.5) == 0 and r.expire(1.5) == 1 and r.take_dropped() == 1 and r.pending == 0


@pytest.mark.parametrize("datagram, kind, reason", [
    (b"short", "garbage", "shorter than"),
    (b"XXXX" + bytes(16), "garbage", "bad fragment magic"),
    (HEADER.pack(b"V2IF", 1, 1, 90, 100) + bytes(20), "garbage", "overruns"),
    (HEADER.pack(b"V2IF", 1, 1, 0, 10_000) + bytes(100), "oversized", "over max_size"),
])
def test_bad_fragments_say_why(datagram, kind, reason):
    with pytest.raises(FragmentError, match=reason) as info:
        Reassembler(max_size=1000).add(datagram, "p", 0.0)
    assert info.value.kind == kind


# -- bookkeeping -------------------------------------------------------------------------
def test_sequence_window_tells_duplicates_from_reordering():
    w = _SeqWindow()
    assert [w.check(s) for s in (0, 1, 3, 2, 2, 3, 10, 5, 5)] == \
        ["new", "new", "new", "reordered", "duplicate", "duplicate", "new", "reordered", "duplicate"]
    assert w.check(5000) == "new" and w.check(3000) == "reordered"


def test_open_bus_names_known_backends_and_options():
    with pytest.raises(TransportError, match="unknown transport backend 'can'; known: .*udp.*zenoh"):
        open_bus("can", prefix="v2i/x", sender="a")
    with pytest.raises(TransportError, match="no option 'colour'.*datagram_size"):
        open_bus("udp", prefix="v2i/x", sender="a", colour="red")
    with pytest.raises(KeyExprError, match="prefix"):
        open_bus("udp", prefix="v2i//x", sender="a", port=0)


def test_numpy_frame_counts_its_bytes():
    import numpy as np

    frame = np.arange(480 * 640 * 3, dtype=np.uint8).reshape(480, 640, 3)
    msg = decode(encode("cam", "v2i/r/camera/rsu_cam", 0.1, 0, frame))
    assert msg.payload == frame.tobytes()
    with pytest.raises(ValueError, match="contiguous"):
        encode("cam", "k", 0.0, 0, frame[:, ::2])
