"""The AV computer's side of the vehicle bus: AV_Status in, AV_Command and AV_Heartbeat out (bridges.can).

Every frame is checked by the DBC codec (CRC-8, ranges, enums) and the rolling
counter check; a bad frame is counted by its reason and dropped, never raised.
Our own frames come back on a multicast bus and are recognised by their id.
Each AV_Command carries the Counter of the AV_Status it answers (StatusEcho):
the gateway's lockstep contract (`sync = "echo"`) applies it one step after
that status.
"""
from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass

import can

from bridges.can.bus import BusConfig, open_bus
from bridges.can.codec import (AppState, CavCodec, CavCommand, CavHeartbeat, CavStatus, FrameError, Mode,
                               RollingCounter, RxChecker)

from av_app.config import CanSection


@dataclass(frozen=True)
class ReceivedStatus:
    status: CavStatus
    wall: float  # time.monotonic() when it was taken off the bus


def bus_config(cfg: CanSection) -> BusConfig:
    return BusConfig(interface=cfg.interface, channel=cfg.channel or None, bitrate=cfg.bitrate or None,
                     port=cfg.port or None, iface=cfg.iface)


class CanDriver:
    def __init__(self, cfg: CanSection, dbc=None, bus: can.BusABC | None = None):
        self.cfg = cfg
        self.codec = CavCodec(dbc)
        self.checker = RxChecker(self.codec)
        self.bus = bus if bus is not None else open_bus(bus_config(cfg))
        self.counter = RollingCounter()
        self.hb_counter = RollingCounter()
        self.sent = Counter()  # commands, heartbeats
        self.ignored = Counter()  # frames that are not for us
        self.send_errors = 0

    @property
    def rejected(self) -> Counter:
        return self.checker.rejected

    def poll(self, timeout: float = 0.0, limit: int = 1000) -> list[ReceivedStatus]:
        """Every valid AV_Status waiting on the bus (the first wait up to `timeout` s)."""
        out: list[ReceivedStatus] = []
        wait = timeout
        for _ in range(limit):
            try:
                msg = self.bus.recv(wait)
            except Exception as exc:  # a broken adapter: counted, the caller goes on
                self.ignored[f"recv error: {type(exc).__name__}"] += 1
                break
            if msg is None:
                break
            wait = 0.0
            status = self._check(msg)
            if status is not None:
                out.append(ReceivedStatus(status, time.monotonic()))
        return out

    def _check(self, msg: can.Message) -> CavStatus | None:
        own = {self.codec.command_id, self.codec.heartbeat_id}
        if msg.arbitration_id in own and not msg.is_extended_id:
            self.ignored["own frame"] += 1
            return None
        try:
            value = self.checker.check(msg)
        except FrameError:
            return None  # tallied by the checker with its reason
        except Exception as exc:  # never let a frame kill the app
            self.checker.rejected[f"internal: {type(exc).__name__}"] += 1
            return None
        if isinstance(value, CavStatus):
            return value
        self.ignored[type(value).__name__] += 1
        return None

    def send_command(self, accel: float, steer: float, mode: Mode, echo: int) -> int:
        """Send one AV_Command answering the status with Counter `echo`; returns its own Counter."""
        lo, hi = self.codec.limits("AV_Command", "AccelRequest")
        accel = min(max(accel, lo), hi)
        lo, hi = self.codec.limits("AV_Command", "SteerAngleRequest")
        steer = min(max(steer, lo), hi)
        counter = self.counter.next()
        data = self.codec.encode_command(CavCommand(accel, steer, mode, False, echo, counter))
        self._send(self.codec.command_id, data, "AV_Command")
        return counter

    def send_heartbeat(self, state: AppState) -> None:
        if self.codec.heartbeat_id is None:
            return
        data = self.codec.encode_heartbeat(CavHeartbeat(state, self.hb_counter.next()))
        self._send(self.codec.heartbeat_id, data, "AV_Heartbeat")

    def _send(self, frame_id: int, data: bytes, name: str) -> None:
        msg = can.Message(arbitration_id=frame_id, data=data, is_extended_id=self.codec.is_extended(name))
        try:
            self.bus.send(msg, timeout=0.1)
            self.sent[name] += 1
        except Exception:  # a full or broken bus: counted; the gateway's timeout policy covers us
            self.send_errors += 1

    def close(self) -> None:
        try:
            self.bus.shutdown()
        except Exception:
            pass
