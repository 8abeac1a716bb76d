"""AB3418-like framing in bridges/ab3418.py: FCS (S5), the GetShortStatus frame (S6), stuffing, the
stream decoder's error kinds, message layouts (S7 sizes)."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridges import ab3418 as a


def test_S5_fcs_check_value_and_residue():
    """ANCHORS S5: CRC-16/X.25 of "123456789" is 0x906E; the register over data + FCS ends at 0xF0B8."""
    assert a.crc16_x25(b"123456789") == 0x906E
    body = bytes.fromhex("0513c084")
    assert a.fcs16_update(0xFFFF, body + a.fcs_bytes(body)) == 0xF0B8
    assert a.fcs_ok(body + a.fcs_bytes(body))


def test_S6_get_short_status_request_bytes():
    """ANCHORS S6: GetShortStatus to controller 1 is 7E 05 13 C0 84 FE F0 7E (FCS low byte first)."""
    assert a.request(a.GET_SHORT_STATUS, station=1) == bytes.fromhex("7E0513C084FEF07E")
    assert a.station_address(1) == 0x05  # S4: (station << 2) + 1


def test_S6_fcs_byte_order_is_configurable():
    lsb = a.request(a.GET_SHORT_STATUS, fcs_order=a.LSB_FIRST)
    msb = a.request(a.GET_SHORT_STATUS, fcs_order=a.MSB_FIRST)
    assert msb == bytes.fromhex("7E0513C084F0FE7E")
    assert a.FrameDecoder(fcs_order=a.MSB_FIRST).feed(msb)[0].msg_type == a.GET_SHORT_STATUS
    # a receiver expecting the other order sees an FCS error, not a frame
    assert a.FrameDecoder(fcs_order=a.LSB_FIRST).feed(msb) == [a.FrameError(a.FCS, bytes.fromhex("0513C084F0FE"))]
    assert lsb != msb


def test_S4_byte_stuffing():
    """ANCHORS S4: 0x7E and 0x7D inside a frame travel as 0x7D, byte ^ 0x20."""
    assert a.stuff(bytes([0x01, 0x7E, 0x7D, 0x02])) == bytes([0x01, 0x7D, 0x5E, 0x7D, 0x5D, 0x02])
    frame = a.encode_frame(1, 0xC4, bytes([0x7E, 0x7D, 0x00]))
    assert frame.count(0x7E) == 2 and frame[0] == frame[-1] == 0x7E
    (decoded,) = a.FrameDecoder().feed(frame)
    assert decoded.data == bytes([0x7E, 0x7D, 0x00])
    with pytest.raises(ValueError):
        a.unstuff(bytes([0x01, 0x7D]))


@settings(max_examples=200, deadline=None)
@given(station=st.integers(0, 63), msg_type=st.integers(0, 255), data=st.binary(max_size=40),
       order=st.sampled_from(a.FCS_ORDERS), control=st.sampled_from(a.CONTROLS))
def test_any_frame_round_trips(station, msg_type, data, order, control):
    frame = a.Frame(a.station_address(station), control, msg_type, data)
    (decoded,) = a.FrameDecoder(fcs_order=order, data_lengths={}).feed(frame.encode(order))
    assert decoded == frame


@settings(max_examples=200, deadline=None)
@given(noise=st.binary(max_size=600))
def test_noise_never_raises_and_a_following_frame_is_recovered(noise):
    """Whatever comes first, a flag resynchronises the decoder and the next good frame decodes."""
    decoder = a.FrameDecoder()
    events = decoder.feed(noise + bytes([a.FLAG]))
    assert all(isinstance(e, (a.Frame, a.FrameError)) for e in events)
    good = a.request(a.GET_LONG_STATUS8)
    assert decoder.feed(good)[-1] == a.Frame(0x05, a.CTRL_UI, a.GET_LONG_STATUS8)


def test_decoder_error_kinds():
    good = a.request(a.GET_SHORT_STATUS)
    cases = {
        "garbage before the first flag": (b"\x11\x22" + good, [a.GARBAGE, "frame"]),
        "garbage between flags": (good + bytes.fromhex("112233445566") + good, ["frame", a.GARBAGE, "frame"]),
        "corrupted FCS": (good[:-2] + bytes([good[-2] ^ 0x01]) + good[-1:], [a.FCS]),
        "truncated below header + FCS": (bytes.fromhex("7E0513C07E"), [a.TRUNCATED]),
        # a SetPreempt needs 1 data byte: cut before it, its last two bytes cannot be an FCS
        "truncated below its type's length": (bytes.fromhex("7E0513C09BFEF07E"), [a.TRUNCATED]),
        "aborted (7D 7E)": (bytes.fromhex("7E0513C0847D7E"), [a.TRUNCATED]),
        "oversize": (bytes([0x7E, 0x05, 0x13, 0xC0, 0x84]) + bytes(300) + bytes([0x7E]) + good,
                     [a.OVERSIZE, "frame"]),
        "idle flags": (bytes([0x7E] * 5) + good + bytes([0x7E] * 3), ["frame"]),
    }
    for name, (stream, expected) in cases.items():
        events = a.FrameDecoder().feed(stream)
        kinds = ["frame" if isinstance(e, a.Frame) else e.kind for e in events]
        assert kinds == expected, name


def test_oversize_limit_is_configurable():
    frame = a.encode_frame(1, 0xCC, bytes(32))
    assert isinstance(a.FrameDecoder(max_frame=38).feed(frame)[0], a.Frame)
    assert a.FrameDecoder(max_frame=37).feed(frame)[0].kind == a.OVERSIZE


def test_S7_status_message_sizes():
    """ANCHORS S7 (PATH msgs.h): GetLongStatus8 request 8 bytes, answer 40 bytes framed."""
    assert len(a.request(a.GET_LONG_STATUS8)) == 8
    status = a.LongStatus8(status=1, greens=0x22, ttc_a_min=a.tenths(12.34), ttc_b_max=a.tenths(None))
    data = status.encode()
    assert len(data) == 32 and len(a.encode_frame(1, 0xCC, data)) == 40
    assert a.LongStatus8.decode(data) == status
    assert a.from_tenths(status.ttc_a_min) == 12.3 and a.from_tenths(status.ttc_b_max) is None
    assert len(a.encode_frame(1, 0xC4, a.ShortStatus(0x22, 0, 1).encode())) == 11
    assert a.ShortStatus.decode(bytes([0x22, 0x01, 0xFF])) == a.ShortStatus(0x22, 1, 255)


def test_answer_and_error_types():
    assert a.response_type(a.GET_SHORT_STATUS) == 0xC4 and a.error_type(a.GET_SHORT_STATUS) == 0xE4
    assert a.response_type(a.GET_LONG_STATUS8) == 0xCC
    assert a.ErrorResponse.decode(a.ErrorResponse(a.ERR_BAD_VALUE, 1).encode()) == a.ErrorResponse(3, 1)
    assert a.is_request_type(0x84) and not a.is_request_type(0xC4)
