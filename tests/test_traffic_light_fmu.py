"""The TrafficLightController FMU, built and stepped by fmpy (and by the master): serial anchors S1, S2,
S7 through the String ports, the default plans cycle by cycle, preemption (T5), bad input by kind."""
from __future__ import annotations

import csv
import shutil
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from bridges import ab3418 as a
from fmus.traffic_light.plan import design_all_red, design_yellow

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "intersection_signal.toml"
GREEN, YELLOW, RED, DARK = 6, 8, 3, 1
NOT_ACTIVE, ENTRY, DWELL, EXIT = 0, 1, 2, 3


@pytest.fixture(scope="session")
def tlc_fmu() -> Path:
    """Only this FMU is built here: other FMUs are work in progress elsewhere."""
    from fmus.builder import build_all

    (result,) = build_all(ROOT / "build" / "fmus", only=["TrafficLightController"])
    return result.path


def scenario_parameters() -> dict:
    return tomllib.loads(SCENARIO.read_text())["fmus"]["tlc"]["parameters"]


class Tlc:
    """One FMU instance stepped by hand with FMU2Slave (fixed step h)."""

    def __init__(self, fmu: Path, h: float = 0.01, **parameters):
        md = read_model_description(str(fmu))
        self.dir = extract(str(fmu))
        self.vars = {v.name: v for v in md.modelVariables}
        self.h, self.k = h, 0
        self.failed = False
        self.s = FMU2Slave(guid=md.guid, unzipDirectory=self.dir, modelIdentifier="TrafficLightController",
                           instanceName="tlc")
        self.s.instantiate()
        self.s.setupExperiment(startTime=0.0)
        self.set(**parameters)
        self.s.enterInitializationMode()
        self.s.exitInitializationMode()

    @property
    def t(self) -> float:
        return self.k * self.h

    def set(self, **values) -> None:
        for name, value in values.items():
            var = self.vars[name]
            setter = {"Real": self.s.setReal, "Integer": self.s.setInteger, "Boolean": self.s.setBoolean,
                      "String": self.s.setString}[var.type]
            setter([var.valueReference], [value])

    def get(self, name):
        var = self.vars[name]
        getter = {"Real": self.s.getReal, "Integer": self.s.getInteger, "Boolean": self.s.getBoolean,
                  "String": self.s.getString}[var.type]
        value = getter([var.valueReference])[0]
        return value.decode() if isinstance(value, bytes) else value

    def step(self, rx: bytes = b"", **inputs) -> bytes:
        if rx:
            inputs["serial_rx_hex"] = rx.hex()
        self.set(**inputs)
        try:
            self.s.doStep(currentCommunicationPoint=self.t, communicationStepSize=self.h)
        except Exception:
            self.failed = True  # pythonfmu crashes in fmi2FreeInstance after a fatal status (README)
            raise
        self.k += 1
        return bytes.fromhex(self.get("serial_tx_hex"))

    def run_until(self, t_end: float, **inputs) -> bytes:
        out = b""
        while self.t < t_end - 1e-9:
            out += self.step(**inputs)
        return out

    def close(self) -> None:
        if not self.failed:
            self.s.terminate()
            self.s.freeInstance()
            shutil.rmtree(self.dir, ignore_errors=True)


@pytest.fixture
def tlc(tlc_fmu):
    made = []

    def make(h=0.01, **parameters):
        inst = Tlc(tlc_fmu, h, **parameters)
        made.append(inst)
        return inst

    yield make
    for inst in made:
        inst.close()


# -- the built FMU ---------------------------------------------------------------------------------
def test_fmu_validates_with_string_ports_and_a_private_copy_of_the_framing(tlc_fmu):
    assert validate_fmu(str(tlc_fmu)) == []
    md = read_model_description(str(tlc_fmu))
    v = {x.name: x for x in md.modelVariables}
    assert (v["serial_rx_hex"].type, v["serial_rx_hex"].causality, v["serial_rx_hex"].start) == ("String", "input", "")
    assert (v["serial_tx_hex"].type, v["serial_tx_hex"].causality) == ("String", "output")
    for p in range(1, 9):
        assert {f"state_{p}", f"min_end_{p}", f"max_end_{p}", f"split_{p}", f"yellow_{p}", f"call_{p}"} <= set(v)
    assert v["baud"].unit == "bit/s" and v["yellow_2"].unit == "s"
    with zipfile.ZipFile(tlc_fmu) as z:
        bundled = [n for n in z.namelist() if n.endswith("_bundled/ab3418.py")]
        assert len(bundled) == 1
        assert z.read(bundled[0]).decode() == (ROOT / "bridges" / "ab3418.py").read_text()


@pytest.mark.parametrize("baud, ms", [(9600, 1.0417), (19200, 0.5208), (115200, 0.0868)])
def test_S1_one_character_through_the_fmu(tlc, baud, ms):
    """ANCHORS S1: a byte reaches the controller 10 / baud s after it was written (8N1)."""
    t = tlc(h=1e-5, baud=float(baud))
    t.step(rx=b"\x00")
    while t.get("serial_rx_bytes") == 0:
        t.step()
    assert t.get("serial_rx_end_time") * 1e3 == pytest.approx(ms, abs=5e-5)
    assert t.get("serial_rx_end_time") == pytest.approx(10 / baud, abs=1e-12)
    assert t.t - t.h < 10 / baud <= t.t + 1e-12  # first seen at the communication point after its stop bit


def test_S2_1024_bytes_at_9600_8N1_through_the_fmu(tlc):
    """ANCHORS S2: 1024 bytes at 9600 8N1 take 1066.67 ms of simulated time."""
    t = tlc(h=0.001)
    t.step(rx=bytes(range(256)) * 4)
    t.run_until(1.066)
    assert t.get("serial_rx_bytes") == 1023
    t.run_until(1.067)
    assert t.get("serial_rx_bytes") == 1024
    simulated = t.get("serial_rx_end_time")
    assert simulated * 1e3 == pytest.approx(1066.67, abs=0.005), (
        f"simulated {simulated * 1e3:.2f} ms vs the seed paper's measured 1064.3 ms (ANCHORS S3): "
        f"{(simulated - 1.0643) / 1.0643:+.2%}")
    assert abs(simulated - 1.0643) / 1.0643 < 0.01  # S3: within 1 % of the paper's measurement


def test_other_framings_change_the_wire_time(tlc):
    t = tlc(h=0.001, parity="E", stop_bits=2.0, data_bits=8, baud=19200.0)
    t.step(rx=bytes(100))
    t.run_until(0.2)
    assert t.get("serial_rx_end_time") == pytest.approx(100 * 12 / 19200, abs=1e-12)


def test_S7_get_long_status8_round_trip_through_the_fmu(tlc):
    """ANCHORS S7: at 9600 8N1 a GetLongStatus8 poll is 8 + 40 bytes = 50.0 ms of wire time, plus the
    controller turnaround T2 (10 ms): its last byte leaves the line 60.0 ms after the poll was written."""
    t = tlc(h=0.001, **scenario_parameters())
    t.run_until(0.5)
    t0 = t.t
    out = t.step(rx=a.request(a.GET_LONG_STATUS8)) + t.run_until(0.7)
    assert len(out) == 40
    wire = (8 + 40) * 10 / 9600
    assert wire == pytest.approx(0.0500, abs=1e-12)
    assert t.get("serial_tx_end_time") - t0 == pytest.approx(wire + 0.010, abs=1e-9)
    (frame,) = a.FrameDecoder().feed(out)
    status = a.LongStatus8.decode(frame.data)
    assert (frame.msg_type, frame.station) == (0xCC, 1)
    assert status.greens == (1 << 1) | (1 << 5) and (status.phase_a, status.phase_b) == (2, 6)
    assert a.from_tenths(status.ttc_a_min) == a.from_tenths(status.ttc_a_max) == pytest.approx(25.5 - 0.5183, abs=0.05)
    # GetShortStatus: 8 + 11 bytes
    t0 = t.t
    out = t.step(rx=a.request(a.GET_SHORT_STATUS)) + t.run_until(0.9)
    assert a.FrameDecoder().feed(out) == [a.Frame(0x05, a.CTRL_UI, 0xC4, bytes([0x22, 0x00, 0x01]))]
    assert t.get("serial_tx_end_time") - t0 == pytest.approx((8 + 11) * 10 / 9600 + 0.010, abs=1e-9)
    assert t.get("serial_rx_hex") == ""  # consumed


# -- plans, cycle by cycle -----------------------------------------------------------------------------
def windows(splits: dict, yellow: dict, red: dict, group_a=(1, 2, 5, 6)):
    """(green start, yellow start, red start) per used phase in one cycle, from the splits alone."""
    out = {}
    for ring in ((1, 2, 3, 4), (5, 6, 7, 8)):
        t = 0.0
        for p in ring:
            if splits[p] > 0:
                out[p] = (t, t + splits[p] - yellow[p] - red[p], t + splits[p] - red[p])
                t += splits[p]
    return out


def expected_state(win, p, t, cycle):
    if p not in win:
        return DARK
    g, y, r = win[p]
    c = t % cycle
    if g - 1e-9 <= c < y - 1e-9:
        return GREEN
    if y - 1e-9 <= c < r - 1e-9:
        return YELLOW
    return RED


def test_T6_default_eight_phase_plan_full_cycle_phase_by_phase(tlc_fmu):
    """FMU defaults (ANCHORS T6, SUMO NEMA example): cycle 130 s, yellow 3 s, red 2 s; splits 20/45 s."""
    names = [f"state_{p}" for p in range(1, 9)] + [f"min_end_{p}" for p in range(1, 9)] + ["phase_r1", "cycle_time"]
    r = simulate_fmu(str(tlc_fmu), stop_time=260.0, step_size=0.1, output_interval=0.1, output=names)
    splits = {p: 20.0 if p % 2 else 45.0 for p in range(1, 9)}
    win = windows(splits, {p: 3.0 for p in splits}, {p: 2.0 for p in splits})
    assert win[4] == (85.0, 125.0, 128.0) and win[7] == (65.0, 80.0, 83.0)
    for p in range(1, 9):
        expected = np.array([expected_state(win, p, t, 130.0) for t in r["time"]])
        bad = np.nonzero(r[f"state_{p}"] != expected)[0]
        assert bad.size == 0, f"phase {p} differs at t = {r['time'][bad[:5]]}"
    first = r[0]
    assert [first[f"min_end_{p}"] for p in (1, 2, 3, 4)] == pytest.approx([15.0, 20.0, 65.0, 85.0])
    np.testing.assert_allclose(r["cycle_time"], r["time"] % 130.0, atol=1e-6)


def test_scenario_plan_full_cycle_through_the_master(tmp_path, tlc_fmu):
    """scenarios/intersection_signal.toml, run by the master: the 2-phase plan phase by phase for two
    cycles; yellow and red clearance from the ITE helpers for 50 km/h (T1-T3)."""
    from master.run.cosim import CoSimulation
    from master.scenario.loader import load_scenario

    p = scenario_parameters()
    assert p["yellow_2"] == design_yellow(50 / 3.6) == 3.3
    assert p["red_clear_2"] == design_all_red(10.0, 50 / 3.6) == 1.2
    sc = load_scenario(SCENARIO)
    result = CoSimulation(sc, tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    with open(tmp_path / "run" / "timeseries.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    splits = {k: p.get(f"split_{k}", 0.0) for k in range(1, 9)}
    win = windows(splits, {k: p.get(f"yellow_{k}", 3.0) for k in splits}, {k: p.get(f"red_clear_{k}", 2.0) for k in splits})
    assert win == {2: (0.0, 25.5, 28.8), 4: (30.0, 55.5, 58.8), 6: (0.0, 25.5, 28.8), 8: (30.0, 55.5, 58.8)}
    assert len(rows) == 12001
    for row in rows:
        t = float(row["time"])
        for k in (2, 4, 6, 8):
            assert int(float(row[f"tlc.state_{k}"])) == expected_state(win, k, t, 60.0), (t, k)
        assert float(row["tlc.cycle_time"]) == pytest.approx(t % 60.0, abs=1e-6) or t % 60.0 > 60 - 1e-6
    by_t = {round(float(r["time"]), 2): r for r in rows}
    assert float(by_t[10.0]["tlc.min_end_2"]) == float(by_t[10.0]["tlc.max_end_2"]) == pytest.approx(25.5)
    assert float(by_t[10.0]["tlc.min_end_4"]) == pytest.approx(30.0)      # red until the next green
    assert float(by_t[27.0]["tlc.min_end_2"]) == pytest.approx(28.8)      # yellow until red
    assert float(by_t[40.0]["tlc.min_end_2"]) == pytest.approx(60.0)      # red until next cycle's green
    assert [int(float(by_t[x]["tlc.phase_r1"])) for x in (0.0, 29.0, 30.0, 59.0)] == [2, 2, 4, 4]


# -- preemption through the FMU -------------------------------------------------------------------------
def test_T5_preemption_timeline_through_the_fmu(tlc):
    """ANCHORS T5 with the scenario plan: call at 10 s (green 2+6 already served > min(5, 3) s): yellow
    3.3 s and red 1.2 s in full, dwell on 4+8 from 14.5 s for 10 s (call gone at 12 s), exit through
    4+8's clearance to 2+6 green at 29.0 s, then the plan resumes with a full 25.5 s green."""
    t = tlc(h=0.01, **scenario_parameters())
    t.run_until(10.0)
    trace = []
    while t.t < 60.0 - 1e-9:
        t.step(preempt_call=10.0 - 1e-9 <= t.t < 12.0 - 1e-9)
        trace.append((round(t.t, 6), t.get("state_2"), t.get("state_4"), t.get("preempt_state"),
                      t.get("min_end_2"), t.get("min_end_4"), t.get("max_end_4")))
    changes = [row[:4] for prev, row in zip(trace, trace[1:]) if row[1:4] != prev[1:4]]
    changes.insert(0, trace[0][:4])
    assert changes == [
        (10.01, YELLOW, RED, ENTRY),   # entry: 2 + 6 end at once (served 10 s > min(5, 3))
        (13.3, RED, RED, ENTRY),       # phase yellow 3.3 s, not shortened
        (14.5, RED, GREEN, DWELL),     # phase red clearance 1.2 s, then dwell on 4 + 8
        (24.5, RED, YELLOW, EXIT),     # dwell 10 s (the call left at 12 s)
        (27.8, RED, RED, EXIT),
        (29.0, GREEN, RED, NOT_ACTIVE),  # exit phases 2 + 6, plan resumed
        (54.5, YELLOW, RED, NOT_ACTIVE),  # a full 25.5 s green
        (57.8, RED, RED, NOT_ACTIVE),
        (59.0, RED, GREEN, NOT_ACTIVE),
    ]
    at = {row[0]: row for row in trace}
    assert at[10.01][4] == pytest.approx(13.3)                        # min_end_2: the entry yellow's end
    assert at[15.0][5] == pytest.approx(24.5) and at[15.0][6] == pytest.approx(24.5)  # dwell ends at its minimum


def test_T5_dwell_while_the_call_persists_has_an_unknown_end(tlc):
    t = tlc(h=0.01, **scenario_parameters())
    t.run_until(10.0)
    t.run_until(20.0, preempt_call=True)
    assert t.get("preempt_state") == DWELL and t.get("state_4") == GREEN
    assert t.get("min_end_4") == pytest.approx(24.5) and t.get("max_end_4") == -1.0  # J2735: unknown
    t.run_until(40.0, preempt_call=True)
    assert t.get("preempt_state") == DWELL
    t.step(preempt_call=False)
    assert t.get("preempt_state") == EXIT and t.get("state_4") == YELLOW


def test_set_preempt_request_over_the_serial_port(tlc):
    t = tlc(h=0.01, **scenario_parameters())
    t.run_until(10.0)
    out = t.step(rx=a.request(a.SET_PREEMPT, data=b"\x01")) + t.run_until(10.1)
    assert a.FrameDecoder().feed(out) == [a.Frame(0x05, a.CTRL_UI, 0xDB)]
    assert t.get("preempt_state") == ENTRY
    t.run_until(20.0)
    assert t.get("preempt_state") == DWELL
    out = t.step(rx=a.request(a.SET_PREEMPT, data=b"\x00")) + t.run_until(25.0)
    assert a.FrameDecoder().feed(out) == [a.Frame(0x05, a.CTRL_UI, 0xDB)]
    assert t.get("preempt_state") == EXIT  # dwell minimum (10 s from 14.51 s) served at 24.51 s
    t.run_until(35.0)
    assert t.get("preempt_state") == NOT_ACTIVE and t.get("state_2") == GREEN


# -- bad input -------------------------------------------------------------------------------------------
COUNTERS = ("frames_ok", "frames_ignored", "responses_sent", "err_fcs", "err_truncated", "err_garbage",
            "err_oversize", "err_unknown_type", "err_bad_request", "err_overrun", "err_rx_overflow")
GOOD = a.request(a.GET_SHORT_STATUS)


def corrupt_fcs(frame: bytes) -> bytes:
    return frame[:-2] + bytes([frame[-2] ^ 0xFF]) + frame[-1:]


BAD_INPUT = {
    # name: (bytes, counter deltas, expected answers as (type, data))
    "corrupted FCS": (corrupt_fcs(GOOD), {"err_fcs": 1}, []),
    "truncated frame": (bytes.fromhex("7E0513C07E"), {"err_truncated": 1}, []),
    "truncated before its data": (bytes.fromhex("7E0513C09BFEF07E"), {"err_truncated": 1}, []),
    "garbage between flags": (bytes.fromhex("7E112233445566778899AA7E"), {"err_garbage": 1}, []),
    "garbage before a frame": (bytes.fromhex("AABBCC") + GOOD, {"err_garbage": 1, "frames_ok": 1, "responses_sent": 1},
                               [(0xC4, None)]),
    "oversize frame": (bytes([0x7E, 0x05, 0x13, 0xC0, 0x84]) + bytes(300) + bytes([0x7E]), {"err_oversize": 1}, []),
    "unknown request type": (a.request(0x8F), {"frames_ok": 1, "err_unknown_type": 1, "responses_sent": 1},
                             [(0xEF, bytes([a.ERR_NO_SUCH_NAME, 0]))]),
    "answer type sent to the controller": (a.request(0xC4, data=bytes(3)), {"frames_ok": 1, "err_unknown_type": 1}, []),
    "wrong length": (a.request(a.GET_SHORT_STATUS, data=b"\x00"), {"frames_ok": 1, "err_bad_request": 1,
                     "responses_sent": 1}, [(0xE4, bytes([a.ERR_MESS_LEN, 0]))]),
    "bad value": (a.request(a.SET_PREEMPT, data=b"\x02"), {"frames_ok": 1, "err_bad_request": 1, "responses_sent": 1},
                  [(0xFB, bytes([a.ERR_BAD_VALUE, 1]))]),
    "other station": (a.request(a.GET_SHORT_STATUS, station=2), {"frames_ignored": 1}, []),
    "broadcast poll": (a.request(a.GET_SHORT_STATUS, control=a.CTRL_BROADCAST), {"frames_ok": 1}, []),
}


@pytest.fixture(scope="module")
def reference_states(tlc_fmu):
    """Signal states of the scenario plan with no serial traffic, one row per step."""
    t = Tlc(tlc_fmu, 0.01, **scenario_parameters())
    rows = []
    for _ in range(300):
        t.step()
        rows.append([t.get(f"state_{p}") for p in (2, 4, 6, 8)])
    t.close()
    return rows


@pytest.mark.parametrize("case", list(BAD_INPUT))
def test_bad_input_is_counted_by_kind_and_the_plan_keeps_running(tlc, reference_states, case):
    data, deltas, answers = BAD_INPUT[case]
    t = tlc(h=0.01, **scenario_parameters())
    t.run_until(1.0)
    out = t.step(rx=data)
    states = [[t.get(f"state_{p}") for p in (2, 4, 6, 8)]]
    while t.t < 2.0 - 1e-9:
        out += t.step()
        states.append([t.get(f"state_{p}") for p in (2, 4, 6, 8)])
    counts = {name: t.get(name) for name in COUNTERS}
    assert counts == {name: deltas.get(name, 0) for name in COUNTERS}, case
    frames = a.FrameDecoder().feed(out)
    assert len(frames) == len(answers), case
    for frame, (msg_type, answer_data) in zip(frames, answers):
        assert frame.msg_type == msg_type and (answer_data is None or frame.data == answer_data), case
    # the controller is still answering, and its plan never noticed
    out = t.step(rx=GOOD) + t.run_until(2.5)
    assert [f.msg_type for f in a.FrameDecoder().feed(out)] == [0xC4], case
    assert states == reference_states[100:200]


def test_request_flood_faster_than_the_line(tlc):
    """50 polls written at once: the line delivers one every 8.3 ms, each answer takes T2 + 41.7 ms; polls
    that arrive while an answer is outstanding are dropped (max_pending_requests = 1) and counted."""
    t = tlc(h=0.001, **scenario_parameters())
    t.run_until(1.0)
    t0 = t.t
    out = t.step(rx=a.request(a.GET_LONG_STATUS8) * 50) + t.run_until(2.0)
    c, busy_until, accepted = 10 / 9600, -1.0, 0
    for i in range(50):
        arrival = t0 + 8 * (i + 1) * c
        if arrival >= busy_until - 1e-9:
            accepted += 1
            busy_until = arrival + 0.010 + 40 * c
    assert 1 < accepted < 50
    frames = a.FrameDecoder().feed(out)
    assert len(frames) == accepted and all(f.msg_type == 0xCC for f in frames)
    assert t.get("responses_sent") == accepted and t.get("err_overrun") == 50 - accepted
    assert t.get("frames_ok") == 50 and t.get("serial_idle")


def test_receive_buffer_overflow_is_counted(tlc):
    t = tlc(h=0.01, rx_buffer_size=100)
    t.step(rx=bytes(250))
    t.run_until(0.5)
    assert t.get("err_rx_overflow") == 150 and t.get("serial_rx_bytes") == 100


def test_invalid_hex_input_is_an_error_naming_the_input(tlc_fmu, tlc):
    """Not line noise (that arrives as bytes) but a broken contract of whoever sets the input."""
    from fmpy.fmi1 import FMICallException

    messages = []
    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        simulate_fmu(str(tlc_fmu), stop_time=0.1, start_values={"serial_rx_hex": "zz"},
                     logger=lambda *args: messages.append(args[-1].decode()), debug_logging=True)
    assert any("serial_rx_hex is not hexadecimal" in m for m in messages), messages
    t = tlc()
    t.step(rx=GOOD)
    with pytest.raises(FMICallException, match="fmi2DoStep"):
        t.step(serial_rx_hex="7e 05 1")


@pytest.mark.parametrize("name, value", [("yellow_2", 2.5), ("yellow_4", 3.05), ("split_2", 8.0), ("parity", "X"),
                                         ("preempt_dwell_phase_r1", 6), ("baud", 0.0)])
def test_invalid_parameters_fail_initialisation_naming_them(tlc_fmu, name, value):
    from fmpy.fmi1 import FMICallException

    messages = []
    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        simulate_fmu(str(tlc_fmu), stop_time=0.1, start_values={name: value},
                     logger=lambda *args: messages.append(args[-1].decode()), debug_logging=True)
    assert any(f"{name} = " in m for m in messages), messages


def test_T1_mutcd_guidance_is_a_warning_not_an_error(tlc_fmu):
    messages = []
    r = simulate_fmu(str(tlc_fmu), stop_time=1.0, start_values={"yellow_2": 7.0, "split_2": 49.0, "split_1": 16.0},
                     logger=lambda *args: messages.append(args[-1].decode()), debug_logging=True,
                     output=["state_2"])
    assert len(r) > 1
    assert any("MUTCD" in m and "yellow_2 = 7 s" in m for m in messages), messages


def test_builder_bundles_only_existing_bridge_modules(tmp_path):
    """fmus/builder.py stages bridges/<name>.py for `fmus._bundled.<name>` imports, and says when it is missing."""
    from fmus.builder import BuildError, FmuSource

    folder = tmp_path / "fmus" / "thing"
    folder.mkdir(parents=True)
    (folder / "slave.py").write_text("from fmus._bundled import ab3418\nimport fmus._bundled.nosuchcodec\n")
    with pytest.raises(BuildError, match=r"imports fmus._bundled.nosuchcodec, but .*bridges/nosuchcodec.py does not exist"):
        FmuSource(folder, "Thing").staged_files()
    (folder / "slave.py").write_text("from fmus._bundled import ab3418\n")
    staged = {str(rel): path for path, rel in FmuSource(folder, "Thing").staged_files()}
    assert staged["_bundled/ab3418.py"] == ROOT / "bridges" / "ab3418.py"
    assert "thing/slave.py" in staged and "units.py" in staged
