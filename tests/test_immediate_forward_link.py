"""The master's real-radio link ([v2x] mode = "rsu", master.links.rsu_link): the scenario keys, the link's timing
on a fake clock (lockstep holds a frame and delivers it at t_tx + the measured delay; realtime at the
current step), matching, losses, late/duplicate/foreign forwards and refusals by reason, and the air's hook
driving the emulated box process over loopback.
"""
from __future__ import annotations

import json
import select
import socket
import subprocess
import sys
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import pytest

from bridges import immediate_forward as imf
from bridges.security import PSID_BSM, PSID_SPAT_MAP, PSID_SURROGATE_BSM, ScenarioCA, Signer, oer, time64_us
from bridges.udp_endpoint import Endpoint
from bridges.v2x import AIR_ARRIVAL, SEND, stamp_ns, stamp_s
from master.links.radio_bridge import RadioBridge, parse_v2x
from master.links.rsu_link import RsuLink
from test_immediate_forward import BSM, MAP, OTHER_BSM, SPAT

STATIONS = {"rsu": {"position": [6.5, 6.5, 6.0]}, "cav": {"position": [30.0, 0.0, 0.0]}}


@pytest.fixture(scope="module")
def signer():
    start = datetime.now(timezone.utc) - timedelta(hours=1)  # valid from an hour before now
    ca = ScenarioCA.create(start=start)
    return Signer(ca.issue("rsu", [PSID_BSM, PSID_SURROGATE_BSM, PSID_SPAT_MAP], start=start))


def _now_us() -> int:
    return time64_us(datetime.now(timezone.utc).timestamp())


def _parse(table):
    problems = []
    spec = parse_v2x(table, {}, lambda k, m: problems.append((k, m)))
    return spec, problems


RSU_TABLE = {"mode": "rsu", "rsu": "127.0.0.1:1516", "obu_listen": "127.0.0.1:47900", "rsu_station": "rsu",
             "obu_station": "cav", "stations": STATIONS}


# -- the scenario keys -----------------------------------------------------------------------------------------
def test_rsu_mode_keys_are_read_and_round_trip():
    spec, problems = _parse({**RSU_TABLE, "obu_format": "immediate-forward", "signature": "rsu",
                             "forward_timeout_s": 0.25, "tx_mode": "ALT",
                             "messages": {"map": {"psid": "0xE0000017", "channel": 180}}})
    assert problems == []
    link = spec.rsu
    assert link.rsu == Endpoint("127.0.0.1", 1516) and link.obu_listen == Endpoint("127.0.0.1", 47900)
    assert (link.rsu_station, link.obu_station, link.obu_format, link.signature) == ("rsu", "cav",
                                                                                     "immediate-forward", "rsu")
    assert link.routes["map"].psid == 0xE0000017 and link.routes["map"].channel == 180
    assert link.routes["spat"].channel == imf.DSRC_CHANNEL
    again, problems = _parse(spec.resolved())
    assert problems == [] and again == spec
    cv2x, _ = _parse({**RSU_TABLE, "channel": {"technology": "cv2x"}})
    assert {r.channel for r in cv2x.rsu.routes.routes} == {imf.CV2X_CHANNEL}


@pytest.mark.parametrize("change, key, words", [
    ({"rsu": None}, "v2x.rsu", "no default"),
    ({"obu_listen": None}, "v2x.obu_listen", "no default"),
    ({"rsu": "127.0.0.1"}, "v2x.rsu", "HOST:PORT"),
    ({"obu_listen": "127.0.0.1:70000"}, "v2x.obu_listen", "outside"),
    ({"rsu_station": "rsu1"}, "v2x.rsu_station", "did you mean 'rsu'"),
    ({"obu_station": None}, "v2x.obu_station", "required"),
    ({"obu_station": "rsu"}, "v2x.obu_station", "another station"),
    ({"obu_format": "ieee1609.2"}, "v2x.obu_format", "did you mean 'ieee1609dot2'"),
    ({"signature": "yes"}, "v2x.signature", "ours, rsu"),
    ({"forward_timeout_s": 0}, "v2x.forward_timeout_s", "(0, 10]"),
    ({"messages": {"mapp": {"psid": "0x8002"}}}, "v2x.messages.mapp", "did you mean 'map'"),
    ({"messages": {"spat": {"psid": "0x82"}}}, "v2x.messages.spat.psid", "0x8002 p-encoded"),
    ({"mode": "channel"}, "v2x.rsu", "only with mode = \"rsu\""),
])
def test_bad_rsu_keys_are_named(change, key, words):
    table = {**RSU_TABLE, **change}
    table = {k: v for k, v in table.items() if v is not None}
    spec, problems = _parse(table)
    assert spec is None
    hits = [m for k, m in problems if k == key]
    assert hits and words in hits[0], problems


# -- the link's logic on a fake clock -----------------------------------------------------------------------------
class FakeDevices:
    """The RSU and the OBU as the link sees them: records sent, forwards queued at wall times; the clock
    moves only when the link waits (next_datagram) or the test says."""

    def __init__(self, delay: float | None = 0.025, fmt=lambda record: imf.parse(record).payload):
        self.now = 100.0
        self.delay, self.fmt = delay, fmt
        self.records: list[bytes] = []
        self.queue: list[tuple[float, bytes, str]] = []

    def send(self, data: bytes) -> None:
        self.records.append(data)
        if self.delay is not None:
            self.queue.append((self.now + self.delay, self.fmt(data), "192.0.2.7:5000"))
            self.queue.sort(key=lambda item: item[0])

    def next_datagram(self, timeout: float):
        if self.queue and self.queue[0][0] <= self.now + timeout:
            item = self.queue.pop(0)
            self.now = max(self.now, item[0])
            return item
        self.now += timeout
        return None

    def clock(self) -> float:
        return self.now


def _link(devices, lockstep=True, **spec_changes):
    spec, problems = _parse({**RSU_TABLE, **spec_changes})
    assert problems == []
    log = []
    return RsuLink(spec.rsu, devices.send, devices.next_datagram, log.append, clock=devices.clock,
                   lockstep=lockstep, t0=0.0), log


def _steps(link, devices, t_from: float, t_to: float, h: float = 0.01, wall_per_step: float = 0.0):
    out = []
    k0, k1 = round(t_from / h), round(t_to / h)
    for k in range(k0, k1):
        devices.now += wall_per_step
        out += link.due((k + 1) * h)
    return out


def test_lockstep_delivers_at_t_tx_plus_the_measured_delay(signer):
    devices = FakeDevices(delay=0.025, fmt=lambda r: imf.parse(r).payload)  # the OBU forwards the 1609.2 data
    link, log = _link(devices, obu_format="ieee1609dot2")
    envelope = signer.sign(BSM, PSID_SURROGATE_BSM, _now_us())
    link.transmit("rsu", 7, 1.0, envelope, {SEND: stamp_ns(1.0)}, {"subject": "ev", "frame_t": 0.95})
    record = imf.parse(devices.records[0])
    assert (record.type, record.psid, record.signature, record.payload) == ("BSM", 0x7F, False, envelope)
    assert link.due(1.01) == [] and link.due(1.02) == []
    assert devices.now == pytest.approx(100.02)  # held while the frame could still arrive within each step
    got = link.due(1.03)
    assert len(got) == 1
    d = got[0]
    assert d.arrival == pytest.approx(1.025) and d.payload == envelope and d.stamps == {SEND: stamp_ns(1.0)}
    assert (d.receiver, d.sender, d.seq, d.about) == ("cav", "rsu", 7, {"subject": "ev", "frame_t": 0.95})
    delivered = [e for e in log if e["event"] == "v2x_delivered"]
    assert delivered[0]["latency_s"] == pytest.approx(0.025) and delivered[0]["via"] == "rsu"
    assert delivered[0]["subject"] == "ev" and delivered[0]["from"] == "rsu" and delivered[0]["to"] == "cav"
    section = link.section()
    assert section["records_sent"] == 1 and section["delivered"] == 1 and section["wall_delay_ms"]["p50"] == \
        pytest.approx(25.0)
    assert section["held_wall_s"] == pytest.approx(0.025)


def test_lockstep_on_a_slow_loop_needs_no_wait_and_keeps_the_delay(signer):
    devices = FakeDevices(delay=0.004)
    link, _ = _link(devices, signature="rsu", obu_format="bare")
    link.transmit("rsu", 1, 0.5, signer.sign(SPAT, PSID_SPAT_MAP, _now_us()))
    record = imf.parse(devices.records[0])
    assert record.signature is True and record.payload == SPAT  # the RSU signs: the bare frame goes
    got = _steps(link, devices, 0.5, 0.52, wall_per_step=0.05)  # every step takes 50 ms of wall time
    assert [round(d.arrival, 6) for d in got] == [0.504] and link.held_s == 0.0


def test_a_frame_not_back_in_time_is_lost_and_its_late_forward_counted(signer):
    devices = FakeDevices(delay=None)
    link, log = _link(devices, forward_timeout_s=0.05)
    envelope = signer.sign(MAP, PSID_SPAT_MAP, _now_us())
    link.transmit("rsu", 3, 2.0, envelope)
    assert _steps(link, devices, 2.0, 2.1) == []
    dropped = [e for e in log if e["event"] == "v2x_dropped"]
    assert [(e["reason"], e["t"], e["seq"]) for e in dropped] == [("timeout", 2.0, 3)]
    assert devices.now - 100.0 == pytest.approx(0.05, abs=0.011)  # held no longer than the timeout (+1 step)
    devices.queue.append((devices.now, envelope, "192.0.2.7:5000"))
    assert link.due(2.11) == []
    assert link.counts["late"] == 1 and link.counts["lost"] == 1 and link.counts["delivered"] == 0


def test_duplicates_foreign_frames_and_garbage_are_counted_never_raised(signer):
    devices = FakeDevices(delay=0.002)
    link, log = _link(devices)
    envelope = signer.sign(BSM, PSID_SURROGATE_BSM, _now_us())
    link.transmit("rsu", 1, 0.0, envelope)
    assert len(link.due(0.01)) == 1
    foreign_bsm = signer.sign(OTHER_BSM, PSID_BSM, _now_us())  # another radio's (here: the same CA's) BSM
    for data in (envelope, foreign_bsm, b"garbage", b"", oer.unsecured(b"\x00\x1f\x00"), b"\x03\x80"):
        devices.queue.append((devices.now, data, "192.0.2.7:5000"))
    got = link.due(0.02)
    assert [d.payload for d in got] == [foreign_bsm] and got[0].arrival == 0.02 and got[0].stamps == {}
    section = link.section()
    assert section["duplicate"] == 1 and section["foreign"] == 1 and section["obu_refused"] == 4
    assert section["obu_refused_by_reason"] == {"empty": 1, "not-1609dot2": 2, "unknown-message": 1}
    assert {e["event"] for e in log} >= {"v2x_duplicate", "v2x_foreign", "v2x_obu_refused"}
    foreign = obu_bare = FakeDevices(delay=None)
    link, _ = _link(obu_bare, obu_format="bare")
    obu_bare.queue.append((obu_bare.now, OTHER_BSM, "192.0.2.7:5000"))
    got = link.due(0.01)
    assert [d.payload for d in got] == [oer.unsecured(OTHER_BSM)]  # a bare foreign frame: unsecured 1609.2 data
    assert foreign.records == []


def test_frames_the_rsu_must_not_send_are_dropped_with_the_reason(signer):
    devices = FakeDevices()
    link, log = _link(devices)
    link.transmit("rsu", 1, 0.0, signer.sign(BSM, PSID_BSM, _now_us()))  # signed 0x20: the bsm route, fine
    link.transmit("rsu", 2, 0.0, b"\x80\x00")  # not a MessageFrame
    link.transmit("rsu", 3, 0.0, oer.unsecured(bytes.fromhex("001f0000")))  # a TIM: no route
    strict, slog = _link(FakeDevices(), messages={"surrogate_bsm": {"psid": "0x20"}})
    strict.transmit("rsu", 4, 0.0, signer.sign(BSM, PSID_SURROGATE_BSM, _now_us()))  # signed 0x7F, sent 0x20
    assert len(devices.records) == 1 and link.section()["not_sent_by_reason"] == {"no-route": 1, "not-j2735": 1}
    assert strict.section()["not_sent_by_reason"] == {"psid-mismatch": 1}
    assert [e["reason"] for e in log + slog if e["event"] == "v2x_dropped"] == ["not_sent"] * 3


def test_realtime_delivers_at_the_step_that_takes_the_forward(signer):
    devices = FakeDevices(delay=0.03)
    link, _ = _link(devices, lockstep=False)
    link.transmit("rsu", 1, 0.0, signer.sign(BSM, PSID_SURROGATE_BSM, _now_us()))
    got = _steps(link, devices, 0.0, 0.1, wall_per_step=0.01)
    assert [round(d.arrival, 6) for d in got] == [0.03] and link.held_s == 0.0


# -- the hook with the emulated box over loopback ------------------------------------------------------------------
class FakeBus:
    def __init__(self):
        self.published = []

    def subscribe(self, key, callback=None):
        return SimpleNamespace(close=lambda: None)

    def publish(self, key, payload, t_sim, stamps=None):
        self.published.append((key, payload, t_sim, dict(stamps or {})))


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_air_hook_goes_through_the_box_process(signer, tmp_path):
    obu_port = _free_udp_port()
    delay_ms = 30.0
    box = subprocess.Popen([sys.executable, "-m", "bridges.rsu_box", "--listen", "127.0.0.1:0", "--forward",
                            f"127.0.0.1:{obu_port}", "--delay-ms", str(delay_ms), "--obu-format", "bare",
                            "--log", str(tmp_path / "box.jsonl")],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([box.stdout], [], [], 30)
        assert ready
        box_address = json.loads(box.stdout.readline())["address"]
        spec, problems = _parse({**RSU_TABLE, "rsu": box_address, "obu_listen": f"127.0.0.1:{obu_port}",
                                 "obu_format": "bare"})
        assert problems == []
        log, bus = [], FakeBus()
        ctx = SimpleNamespace(bus=bus, events=log.append, fmus={}, t0=0.0, world=None, mode="lockstep",
                              scenario=SimpleNamespace(world=None), stamp_time=lambda t: t)
        hook = RadioBridge(spec)
        hook.open(ctx)
        frames = {}
        h = 0.01
        for k in range(60):
            t_next = (k + 1) * h
            if k % 5 == 0:  # 20 Hz: a surrogate BSM, and a MAP now and then
                psid, frame = (PSID_SPAT_MAP, MAP) if k % 20 == 0 else (PSID_SURROGATE_BSM, BSM)
                envelope = signer.sign(frame, psid, _now_us() + k)
                frames[envelope] = k * h
                hook._on_tx(SimpleNamespace(key="v2x/tx/rsu", t_sim=k * h, sender="rsu", seq=k, payload=envelope,
                                            stamps={SEND: stamp_ns(k * h)}))
            if k == 30:  # garbage at the OBU port: counted, never raised
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                    s.sendto(b"\x00", ("127.0.0.1", obu_port))
            hook.after_step(k, t_next)
        for k in range(60, 110):  # let the last ones come back
            hook.after_step(k, (k + 1) * h)
        section = hook.close()
    finally:
        box.terminate()
        out, _ = box.communicate(timeout=10)
    assert box.returncode == 0
    rsu = section["rsu"]
    assert rsu["records_sent"] == 12 and rsu["delivered"] == 12 and rsu["lost"] == 0, rsu
    assert rsu["obu_refused_by_reason"] == {"not-a-message-frame": 1}
    assert json.loads(out.strip().splitlines()[-1])["forwarded"] == 12
    rx = [p for p in bus.published if p[0] == "v2x/rx/cav"]
    assert len(rx) == 12
    for _, payload, t_sim, stamps in rx:
        t_tx = frames[payload]  # the AV app gets the frame the RSU app published, signed as it was
        assert t_sim - t_tx >= delay_ms / 1e3 and stamp_s(stamps[AIR_ARRIVAL]) == pytest.approx(t_sim)
        assert stamp_s(stamps[AIR_ARRIVAL]) - stamp_s(stamps[SEND]) >= delay_ms / 1e3
    assert max(t for _, _, t, _ in rx) - 0.55 < 0.2  # the delay, not the timeout
    assert [e["event"] for e in log].count("v2x_delivered") == 12


def test_an_obu_listen_address_not_of_this_host_fails_the_run_naming_it():
    from master.errors import SimulationError

    spec, problems = _parse({**RSU_TABLE, "obu_listen": "192.0.2.1:47900"})  # TEST-NET-1: never this host's
    assert problems == []
    ctx = SimpleNamespace(bus=FakeBus(), events=lambda e: None, fmus={}, t0=0.0, world=None, mode="lockstep",
                          scenario=SimpleNamespace(world=None), stamp_time=lambda t: t)
    hook = RadioBridge(spec)
    with pytest.raises(SimulationError, match=r"obu_listen = '192\.0\.2\.1:47900'.*address of this host"):
        hook.open(ctx)
    assert hook.close()["mode"] == "rsu"  # closing after a failed open is safe
