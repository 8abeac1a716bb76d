"""EVSP's serial leg: the RSU app's controller link sends AB3418 SetPreempt in place of its next poll, the
controller model (fmus/traffic_light, its RS-232 UART model) acts on it, and the acknowledgement comes
back with the frame sizes, so the request's wire time is the RS-232 model's (ANCHORS S1: 10 / baud s per
8N1 character; S3: 1064.3 ms per KiB measured at 9600 baud)."""
from __future__ import annotations

import pytest

from bridges import ab3418 as a
from fmus.traffic_light.model import TrafficLightModel
from fmus.traffic_light.plan import PHASES, PhaseTiming, PreemptConfig, TimingPlan
from fmus.traffic_light.preemption import NOT_ACTIVE
from fmus.traffic_light.uart import UartConfig
from rsu_app.controller_link import ControllerLink


def two_phase() -> TimingPlan:
    phases = {p: PhaseTiming(split=30.0 if p % 2 == 0 else 0.0, min_green=5.0, yellow=3.3, red_clear=1.2,
                             max_green=20.0, passage=2.0) for p in PHASES}
    return TimingPlan(phases, cycle=60.0, offset=0.0,
                      preempt=PreemptConfig(min_green=3.0, dwell=10.0, dwell_phases=(4, 8), exit_phases=(2, 6)))


class ModelPort:
    """A pyserial-like port whose far end is the controller model, stepped in simulated time by the test."""

    def __init__(self, model: TrafficLightModel):
        self.model, self.pending, self.out = model, b"", bytearray()
        self.t, self.dt = 0.0, 0.01
        self.written: list[tuple[float, bytes]] = []

    def write(self, data: bytes) -> int:
        self.pending += data
        self.written.append((self.t, bytes(data)))
        return len(data)

    def step(self) -> None:
        rx, self.pending = self.pending, b""
        self.out += self.model.step(self.t, self.dt, rx=rx)
        self.t += self.dt

    def read(self, n: int) -> bytes:
        data, self.out = bytes(self.out[:n]), self.out[n:]
        return data

    def close(self) -> None:
        pass


def run_link(baud: float, seconds: float, preempt_at: float):
    model = TrafficLightModel(two_phase(), UartConfig(baud=baud))
    port = ModelPort(model)
    link = ControllerLink("model://", station=1, baud=int(baud), opener=lambda url: port)
    assert link.open()
    acks, asked = [], False
    while port.t < seconds:
        if not asked and port.t >= preempt_at:
            link.set_preempt(True)
            asked = True
        port.step()
        link.collect()
        acks += [(port.t, ack) for ack in link.collect_preempt()]
    return model, port, link, acks


def test_set_preempt_reaches_the_controller_over_the_serial_line_and_is_acknowledged():
    model, port, link, acks = run_link(9600, 3.0, preempt_at=1.0)
    request = a.request(a.SET_PREEMPT, 1, b"\x01")
    sent = [(t, b) for t, b in port.written if b == request]
    assert len(sent) == 1 and sent[0][0] >= 1.0
    assert len(acks) == 1
    t_ack, ack = acks[0]
    assert ack.on and ack.ok and ack.request_bytes == len(request)
    assert ack.answer_bytes == len(a.encode_frame(1, a.response_type(a.SET_PREEMPT)))
    assert model.controller.pstate != NOT_ACTIVE          # the controller entered preemption
    # the round trip costs at least the two frames' wire time plus the controller's turnaround
    wire = (ack.request_bytes + ack.answer_bytes) * 10 / 9600
    assert t_ack - sent[0][0] >= wire + 0.010 - 0.01 - 1e-9
    assert link.stats()["preempt_requests"] == 1 and link.stats()["preempt_acks"] == 1
    # polling went on before and after the request
    assert link.stats()["answers"] > 10


@pytest.mark.parametrize("baud", [1200, 9600, 115200])
def test_the_preempt_round_trip_follows_the_rs232_model(baud):
    _, port, _, acks = run_link(baud, 4.0, preempt_at=1.0)
    (t_ack, ack), = acks
    t_sent = next(t for t, b in port.written if b[4] == a.SET_PREEMPT)
    wire = (ack.request_bytes + ack.answer_bytes) * 10 / baud   # ANCHORS S1
    # the request starts at the next communication point after the write; acknowledged after wire + turnaround
    assert wire + 0.010 - 0.01 <= t_ack - t_sent <= wire + 0.010 + 0.03


def test_release_is_acknowledged_in_order():
    model = TrafficLightModel(two_phase(), UartConfig(baud=9600))
    port = ModelPort(model)
    link = ControllerLink("model://", opener=lambda url: port)
    link.open()
    link.set_preempt(True)
    first = []
    for _ in range(100):
        port.step()
        link.collect()
        first += link.collect_preempt()
    assert [x.on for x in first] == [True]
    link.set_preempt(False)
    acks = []
    for _ in range(100):
        port.step()
        link.collect()
        acks += link.collect_preempt()
    assert [x.on for x in acks] == [False] and acks[0].ok
