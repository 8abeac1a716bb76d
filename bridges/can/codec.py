"""Typed CAN frames of the connected vehicle: AV_Command, AV_Status, AV_Heartbeat from a DBC.

The database (``cav.dbc`` beside this file, or a user's DBC with the same message
and signal names) is loaded and checked once per :class:`CavCodec`; encoding and
decoding then only touch the compiled cantools messages.

Every frame ends in an 8-bit rolling ``Counter`` and a CRC-8 ``Checksum`` (SAE
J1850: polynomial 0x1D, init 0xFF, final XOR 0xFF) over the frame id (two bytes,
low first) and the payload with the checksum bits zeroed, in the spirit of AUTOSAR
E2E profile 1: the id in the CRC catches a payload sent under the wrong id.

Nothing from the bus is trusted: :meth:`CavCodec.decode` raises :class:`FrameError`
with a short ``reason`` code (``unknown_id``, ``dlc``, ``checksum``, ``range``,
``enum``, ``remote``, ``error_frame``) and a detail naming the signal, and
:class:`RxChecker` adds the per-id counter check (``counter_stuck``) and tallies
every reason, so a receiver counts bad frames and carries on.
"""
from __future__ import annotations

import enum
import math
from collections import Counter as Tally
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cantools

__all__ = ["DEFAULT_DBC", "Mode", "AppState", "CavCommand", "CavStatus", "CavHeartbeat", "CavCodec",
           "FrameError", "EncodeRangeError", "RxChecker", "RollingCounter", "crc8_j1850"]

DEFAULT_DBC = Path(__file__).with_name("cav.dbc")

COMMAND, STATUS, HEARTBEAT = "AV_Command", "AV_Status", "AV_Heartbeat"
# message -> signals the codec reads and writes (a user's DBC must have these names)
_REQUIRED = {
    COMMAND: ("AccelRequest", "SteerAngleRequest", "Mode", "ReverseRequest", "StatusEcho", "Counter", "Checksum"),
    STATUS: ("Speed", "YawRate", "AccelActual", "Mode", "Reverse", "Counter", "Checksum"),
    HEARTBEAT: ("AppState", "Counter", "Checksum"),
}
_OPTIONAL = (HEARTBEAT,)


class Mode(enum.IntEnum):
    MANUAL = 0
    AUTO = 1
    EMERGENCY_STOP = 2
    FALLBACK = 3  # status only: the gateway applies its command-timeout policy


class AppState(enum.IntEnum):
    INIT = 0
    READY = 1
    ENGAGED = 2
    DEGRADED = 3
    FAULT = 4


@dataclass(frozen=True)
class CavCommand:
    """What the AV computer asks of the vehicle (SI units)."""

    accel: float  # m/s^2, negative brakes
    steer: float  # rad, front-wheel angle
    mode: Mode = Mode.AUTO
    reverse: bool = False
    status_echo: int = 0  # Counter of the AV_Status this was computed from
    counter: int = 0


@dataclass(frozen=True)
class CavStatus:
    """What the vehicle reports back (SI units)."""

    speed: float  # m/s
    yaw_rate: float  # rad/s
    accel: float  # m/s^2, actual
    mode: Mode = Mode.MANUAL
    reverse: bool = False
    counter: int = 0


@dataclass(frozen=True)
class CavHeartbeat:
    state: AppState = AppState.READY
    counter: int = 0


class FrameError(ValueError):
    """A frame refused on receive: `reason` is a short code for tallies, `detail` says why."""

    def __init__(self, reason: str, detail: str, frame_id: int | None = None):
        self.reason, self.detail, self.frame_id = reason, detail, frame_id
        where = f"0x{frame_id:X}: " if frame_id is not None else ""
        super().__init__(f"{where}{reason}: {detail}")


class EncodeRangeError(ValueError):
    """A value cannot be sent: names the message and signal."""

    def __init__(self, message: str, signal: str, detail: str):
        self.message, self.signal = message, signal
        super().__init__(f"{message}.{signal}: {detail}")


def _crc8_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return table


_CRC8 = _crc8_table()


def crc8_j1850(data: bytes, crc: int = 0xFF) -> int:
    """CRC-8/SAE-J1850 (check value of b"123456789": 0x4B)."""
    for byte in data:
        crc = _CRC8[crc ^ byte]
    return crc ^ 0xFF


class RollingCounter:
    """The sender's 8-bit alive counter: 0, 1, ..., 255, 0, ..."""

    def __init__(self, start: int = 0):
        self.value = start & 0xFF

    def next(self) -> int:
        value = self.value
        self.value = (value + 1) & 0xFF
        return value


class _Frame:
    """One compiled message: its cantools message, checksum mask and signal limits."""

    def __init__(self, message):
        self.message = message
        self.name = message.name
        self.frame_id = message.frame_id
        self.length = message.length
        self.signals = {s.name: s for s in message.signals}
        zeros = {name: 0 for name in self.signals}
        mask = message.encode({**zeros, "Checksum": 0xFF}, scaling=False, strict=False)
        self.keep = bytes(~b & 0xFF for b in mask)  # AND-mask that zeroes the checksum bits
        self.id_bytes = bytes((self.frame_id & 0xFF, (self.frame_id >> 8) & 0xFF))

    def crc(self, payload: bytes) -> int:
        return crc8_j1850(self.id_bytes + bytes(a & b for a, b in zip(payload, self.keep)))

    def encode(self, values: dict[str, Any]) -> bytes:
        for name, value in values.items():
            sig = self.signals[name]
            if isinstance(value, float) and not math.isfinite(value):
                raise EncodeRangeError(self.name, name, f"not a finite number: {value!r}")
            low, high = sig.minimum, sig.maximum
            if low is not None and value < low or high is not None and value > high:
                unit = f" {sig.unit}" if sig.unit else ""
                raise EncodeRangeError(self.name, name, f"{value!r} outside [{low}, {high}]{unit}")
            if sig.choices is not None and name != "Checksum" and int(value) not in sig.choices:
                raise EncodeRangeError(self.name, name, f"{value!r} is not one of {sorted(sig.choices)}")
        payload = self.message.encode({**values, "Checksum": 0}, strict=False)
        return self.message.encode({**values, "Checksum": self.crc(payload)}, strict=False)

    def decode(self, data: bytes) -> dict[str, Any]:
        if len(data) != self.length:
            raise FrameError("dlc", f"{self.name} has {self.length} bytes, got {len(data)}", self.frame_id)
        values = self.message.decode(data, decode_choices=False, allow_truncated=False)
        expected = self.crc(data)
        if values["Checksum"] != expected:
            raise FrameError("checksum", f"{self.name} Checksum 0x{values['Checksum']:02X}, "
                                         f"expected 0x{expected:02X}", self.frame_id)
        for name, value in values.items():
            sig = self.signals[name]
            if sig.choices is not None and int(value) not in sig.choices:
                raise FrameError("enum", f"{self.name}.{name} = {value} is not one of {sorted(sig.choices)}",
                                 self.frame_id)
            low, high = sig.minimum, sig.maximum
            tol = abs(sig.scale) / 2 if isinstance(sig.scale, (int, float)) else 0.0
            if low is not None and value < low - tol or high is not None and value > high + tol:
                raise FrameError("range", f"{self.name}.{name} = {value} outside [{low}, {high}]", self.frame_id)
        return values


class CavCodec:
    """The connected vehicle's frames, compiled once from `dbc` (default: the shipped cav.dbc)."""

    def __init__(self, dbc: str | Path | None = None):
        self.path = Path(dbc) if dbc is not None else DEFAULT_DBC
        try:
            db = cantools.database.load_file(str(self.path), strict=True)
        except FileNotFoundError:
            raise ValueError(f"DBC file not found: {self.path}") from None
        except Exception as exc:  # cantools raises several parse error types
            raise ValueError(f"cannot load DBC {self.path}: {type(exc).__name__}: {exc}") from exc
        self.frames: dict[str, _Frame] = {}
        for name, signals in _REQUIRED.items():
            try:
                message = db.get_message_by_name(name)
            except KeyError:
                if name in _OPTIONAL:
                    continue
                raise ValueError(f"{self.path}: no message {name!r} (the codec needs "
                                 f"{', '.join(n for n in _REQUIRED if n not in _OPTIONAL)})") from None
            missing = [s for s in signals if s not in {sig.name for sig in message.signals}]
            if missing:
                raise ValueError(f"{self.path}: message {name} lacks signal(s) {', '.join(missing)}")
            if message.is_multiplexed() or message.is_container:
                raise ValueError(f"{self.path}: message {name} must be a plain (not multiplexed) frame")
            self.frames[name] = _Frame(message)
        self._by_id = {(f.frame_id, f.message.is_extended_frame): f for f in self.frames.values()}
        self.command_id = self.frames[COMMAND].frame_id
        self.status_id = self.frames[STATUS].frame_id
        self.heartbeat_id = self.frames[HEARTBEAT].frame_id if HEARTBEAT in self.frames else None

    def is_extended(self, name: str) -> bool:
        return self.frames[name].message.is_extended_frame

    def cycle_time_s(self, name: str) -> float | None:
        ms = self.frames[name].message.cycle_time
        return ms / 1000.0 if ms else None

    def limits(self, message: str, signal: str) -> tuple[float | None, float | None]:
        sig = self.frames[message].signals[signal]
        return sig.minimum, sig.maximum

    # -- encode ---------------------------------------------------------------
    def encode_command(self, cmd: CavCommand) -> bytes:
        return self.frames[COMMAND].encode({
            "AccelRequest": float(cmd.accel), "SteerAngleRequest": float(cmd.steer), "Mode": int(cmd.mode),
            "ReverseRequest": int(bool(cmd.reverse)), "StatusEcho": int(cmd.status_echo),
            "Counter": int(cmd.counter)})

    def encode_status(self, st: CavStatus) -> bytes:
        return self.frames[STATUS].encode({
            "Speed": float(st.speed), "YawRate": float(st.yaw_rate), "AccelActual": float(st.accel),
            "Mode": int(st.mode), "Reverse": int(bool(st.reverse)), "Counter": int(st.counter)})

    def encode_heartbeat(self, hb: CavHeartbeat) -> bytes:
        if HEARTBEAT not in self.frames:
            raise ValueError(f"{self.path} has no {HEARTBEAT} message")
        return self.frames[HEARTBEAT].encode({"AppState": int(hb.state), "Counter": int(hb.counter)})

    # -- decode ---------------------------------------------------------------
    def decode(self, frame_id: int, data: bytes, *, is_extended: bool = False, is_remote: bool = False,
               is_error: bool = False) -> CavCommand | CavStatus | CavHeartbeat:
        """The typed content of one frame, or FrameError saying why not."""
        if is_error:
            raise FrameError("error_frame", "CAN error frame", frame_id)
        frame = self._by_id.get((frame_id, bool(is_extended)))
        if frame is None:
            kind = "extended" if is_extended else "standard"
            raise FrameError("unknown_id", f"no message with {kind} id 0x{frame_id:X} in {self.path.name}",
                             frame_id)
        if is_remote:
            raise FrameError("remote", f"remote frame for {frame.name}", frame_id)
        v = frame.decode(bytes(data))
        if frame.name == COMMAND:
            return CavCommand(v["AccelRequest"], v["SteerAngleRequest"], Mode(v["Mode"]),
                              bool(v["ReverseRequest"]), int(v["StatusEcho"]), int(v["Counter"]))
        if frame.name == STATUS:
            return CavStatus(v["Speed"], v["YawRate"], v["AccelActual"], Mode(v["Mode"]), bool(v["Reverse"]),
                             int(v["Counter"]))
        return CavHeartbeat(AppState(v["AppState"]), int(v["Counter"]))

    def decode_message(self, msg) -> CavCommand | CavStatus | CavHeartbeat:
        """decode() for a python-can Message."""
        data = bytes(msg.data)
        if msg.dlc != len(data) and not msg.is_remote_frame:
            raise FrameError("dlc", f"dlc {msg.dlc} but {len(data)} data bytes", msg.arbitration_id)
        return self.decode(msg.arbitration_id, data, is_extended=msg.is_extended_id,
                           is_remote=msg.is_remote_frame, is_error=msg.is_error_frame)


class RxChecker:
    """Decode plus the per-id counter check, with a tally of every accepted and refused frame.

    A frame whose Counter repeats the last accepted one from the same id is refused
    (``counter_stuck``: a frozen sender or a replayed frame); a jump is accepted and
    the frames it skipped are added to ``counter_gaps`` (lost on the bus).
    """

    def __init__(self, codec: CavCodec):
        self.codec = codec
        self.last_counter: dict[int, int] = {}
        self.accepted = Tally()
        self.rejected = Tally()
        self.counter_gaps = 0

    def check(self, msg) -> CavCommand | CavStatus | CavHeartbeat:
        try:
            value = self.codec.decode_message(msg)
            last = self.last_counter.get(msg.arbitration_id)
            if last is not None:
                step = (value.counter - last) & 0xFF
                if step == 0:
                    raise FrameError("counter_stuck", f"Counter stays at {value.counter}", msg.arbitration_id)
                self.counter_gaps += step - 1
            self.last_counter[msg.arbitration_id] = value.counter
        except FrameError as exc:
            self.rejected[exc.reason] += 1
            raise
        self.accepted[type(value).__name__] += 1
        return value
