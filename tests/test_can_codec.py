"""The CAV CAN codec (bridges/can): the DBC's contract, round trips, and every way a frame is refused."""
from __future__ import annotations

import can
import pytest

from bridges.can.bus import BusConfig, open_bus
from bridges.can.codec import (DEFAULT_DBC, AppState, CavCodec, CavCommand, CavHeartbeat, CavStatus,
                               EncodeRangeError, FrameError, Mode, RollingCounter, RxChecker, crc8_j1850)


@pytest.fixture(scope="module")
def codec() -> CavCodec:
    return CavCodec()


def frame(codec, data: bytes, frame_id=None, **kw) -> can.Message:
    return can.Message(arbitration_id=codec.command_id if frame_id is None else frame_id, data=data,
                       is_extended_id=False, **kw)


def test_dbc_contract(codec):
    """Ids, lengths, cycle times and units the AV app and the docs rely on."""
    assert (codec.command_id, codec.status_id, codec.heartbeat_id) == (0x110, 0x180, 0x500)
    assert codec.cycle_time_s("AV_Command") == 0.010
    assert codec.cycle_time_s("AV_Status") == 0.020
    assert codec.cycle_time_s("AV_Heartbeat") == 0.100
    assert codec.limits("AV_Command", "AccelRequest") == (-15, 15)
    assert codec.limits("AV_Command", "SteerAngleRequest") == (-1, 1)
    assert codec.frames["AV_Status"].signals["Speed"].unit == "m/s"
    assert codec.frames["AV_Command"].signals["Mode"].choices[2] == "EMERGENCY_STOP"


def test_crc8_sae_j1850_check_value():
    assert crc8_j1850(b"123456789") == 0x4B  # the catalogue check value of CRC-8/SAE-J1850
    assert crc8_j1850(b"") == 0x00


@pytest.mark.parametrize("cmd", [
    CavCommand(-2.5, 0.1, Mode.AUTO, False, 3, 7),
    CavCommand(15.0, -1.0, Mode.EMERGENCY_STOP, True, 255, 255),
    CavCommand(-15.0, 1.0, Mode.MANUAL, False, 0, 0),
    CavCommand(0.0011, -0.00049, Mode.AUTO, False, 128, 1),
])
def test_command_round_trip(codec, cmd):
    data = codec.encode_command(cmd)
    assert len(data) == 8
    back = codec.decode(codec.command_id, data)
    assert back.mode is cmd.mode and back.reverse == cmd.reverse
    assert (back.status_echo, back.counter) == (cmd.status_echo, cmd.counter)
    assert back.accel == pytest.approx(cmd.accel, abs=0.0005)  # resolution 0.001 m/s2
    assert back.steer == pytest.approx(cmd.steer, abs=0.00005)  # resolution 0.0001 rad


def test_known_bytes(codec):
    """Little-endian layout written out by hand: accel -2.5 -> raw -2500 = 0xF63C, steer 0.1 -> 1000 = 0x03E8."""
    data = codec.encode_command(CavCommand(-2.5, 0.1, Mode.AUTO, False, 3, 7))
    assert data[:7] == bytes([0x3C, 0xF6, 0xE8, 0x03, 0x01, 0x03, 0x07])
    # CRC over the id (low byte first) and the 8 payload bytes with the checksum byte zeroed
    assert data[7] == crc8_j1850(bytes([0x10, 0x01]) + data[:7] + b"\x00")


def test_status_and_heartbeat_round_trip(codec):
    st = CavStatus(12.34, -0.5, -3.21, Mode.FALLBACK, True, 200)
    assert codec.decode(codec.status_id, codec.encode_status(st)) == st
    hb = CavHeartbeat(AppState.DEGRADED, 9)
    assert codec.decode(codec.heartbeat_id, codec.encode_heartbeat(hb)) == hb


@pytest.mark.parametrize("cmd, signal", [
    (CavCommand(-15.5, 0.0), "AccelRequest"),
    (CavCommand(0.0, 1.2), "SteerAngleRequest"),
    (CavCommand(float("nan"), 0.0), "AccelRequest"),
    (CavCommand(0.0, 0.0, counter=256), "Counter"),
    (CavCommand(0.0, 0.0, status_echo=-1), "StatusEcho"),
    (CavCommand(0.0, 0.0, mode=Mode.FALLBACK), "Mode"),  # FALLBACK is a status, never a request
])
def test_encode_refuses_out_of_range_naming_the_signal(codec, cmd, signal):
    with pytest.raises(EncodeRangeError, match=rf"AV_Command\.{signal}") as info:
        codec.encode_command(cmd)
    assert info.value.signal == signal


def test_decode_rejections(codec):
    good = codec.encode_command(CavCommand(1.0, 0.0, counter=5))
    cases = {
        "checksum": (codec.command_id, good[:3] + bytes([good[3] ^ 0x40]) + good[4:]),
        "dlc": (codec.command_id, good[:7]),
        "unknown_id": (0x7FF, good),
    }
    for reason, (fid, data) in cases.items():
        with pytest.raises(FrameError) as info:
            codec.decode(fid, data)
        assert info.value.reason == reason, info.value
    # a status frame under the command's id: right length, but the id is in the CRC
    status = codec.encode_status(CavStatus(1.0, 0.0, 0.0))
    with pytest.raises(FrameError, match="checksum"):
        codec.decode(codec.command_id, status)
    with pytest.raises(FrameError, match="unknown_id"):
        codec.decode(codec.command_id, good, is_extended=True)
    with pytest.raises(FrameError, match="remote"):
        codec.decode(codec.command_id, b"", is_remote=True)


def test_decode_refuses_raw_values_outside_the_dbc_range(codec):
    """Bytes with a valid CRC but AccelRequest raw 20000 (20 m/s2 > 15) or Mode 3: refused by name."""
    f = codec.frames["AV_Command"]
    base = {"AccelRequest": 0, "SteerAngleRequest": 0, "Mode": 1, "ReverseRequest": 0, "StatusEcho": 0,
            "Counter": 0}

    def forged(**raw):
        payload = f.message.encode({**base, **raw, "Checksum": 0}, scaling=False, strict=False)
        return f.message.encode({**base, **raw, "Checksum": f.crc(payload)}, scaling=False, strict=False)

    with pytest.raises(FrameError, match=r"range: AV_Command\.AccelRequest"):
        codec.decode(codec.command_id, forged(AccelRequest=20000))
    with pytest.raises(FrameError, match=r"enum: AV_Command\.Mode = 3"):
        codec.decode(codec.command_id, forged(Mode=3))
    assert codec.decode(codec.command_id, forged(AccelRequest=15000)).accel == 15.0


def test_rx_checker_counts_stuck_counters_and_gaps(codec):
    rx = RxChecker(codec)
    seq = RollingCounter(254)
    for _ in range(3):  # 254, 255, 0: wraps without a gap
        rx.check(frame(codec, codec.encode_command(CavCommand(0.0, 0.0, counter=seq.next()))))
    stuck = frame(codec, codec.encode_command(CavCommand(0.0, 0.0, counter=0)))
    with pytest.raises(FrameError, match="counter_stuck"):
        rx.check(stuck)
    rx.check(frame(codec, codec.encode_command(CavCommand(0.0, 0.0, counter=4))))  # 1, 2, 3 lost
    for bad in (frame(codec, b"\x00" * 8), frame(codec, b"\x01"), frame(codec, b"\x00" * 8, frame_id=0x123)):
        with pytest.raises(FrameError):
            rx.check(bad)
    assert rx.accepted == {"CavCommand": 4}
    assert rx.rejected == {"counter_stuck": 1, "checksum": 1, "dlc": 1, "unknown_id": 1}
    assert rx.counter_gaps == 3


def test_user_dbc_path(tmp_path):
    """A user's DBC with other ids and scaling but the same names works; one lacking a signal is refused."""
    text = DEFAULT_DBC.read_text().replace("BO_ 272 AV_Command", "BO_ 801 AV_Command") \
        .replace(" 272 ", " 801 ").replace("(0.001,0) [-15|15]", "(0.01,0) [-10|10]")
    (tmp_path / "mine.dbc").write_text(text)
    mine = CavCodec(tmp_path / "mine.dbc")
    assert mine.command_id == 801
    assert mine.decode(801, mine.encode_command(CavCommand(-9.99, 0.0))).accel == pytest.approx(-9.99)
    with pytest.raises(EncodeRangeError, match="AccelRequest"):
        mine.encode_command(CavCommand(-12.0, 0.0))
    (tmp_path / "bad.dbc").write_text(DEFAULT_DBC.read_text().replace("SG_ StatusEcho", "SG_ Echo"))
    with pytest.raises(ValueError, match="AV_Command lacks signal.*StatusEcho"):
        CavCodec(tmp_path / "bad.dbc")
    with pytest.raises(ValueError, match="not found"):
        CavCodec(tmp_path / "missing.dbc")


def test_bus_config_checks_and_virtual_bus(codec):
    assert [k for k, _ in BusConfig("nope").problems()] == ["interface"]
    assert [k for k, _ in BusConfig("udp_multicast", "10.0.0.1").problems()] == ["channel"]
    assert [k for k, _ in BusConfig("udp_multicast", port=70000).problems()] == ["port"]
    assert [k for k, _ in BusConfig("socketcan", "can0", bitrate=-1).problems()] == ["bitrate"]
    assert BusConfig().kwargs() == {"interface": "udp_multicast", "channel": "239.74.163.2", "port": 43113,
                                    "fd": False}
    with pytest.raises(ValueError, match="interface"):
        open_bus(interface="nope")
    a, b = open_bus(interface="virtual", channel="codec-test"), open_bus(interface="virtual", channel="codec-test")
    try:
        a.send(frame(codec, codec.encode_command(CavCommand(3.0, 0.0, counter=1))))
        msg = b.recv(1.0)
        assert codec.decode_message(msg).accel == 3.0
    finally:
        a.shutdown()
        b.shutdown()
