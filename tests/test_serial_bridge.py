"""The master's serial bridge: a pyserial socket:// client talks to the TrafficLightController FMU
through the master; simulated round trips equal the model's wire time + turnaround (ANCHORS S7),
whatever the client's wall-clock pace; bad input never stops the run; [serial] validation."""
from __future__ import annotations

import json
import textwrap
import threading
import time
from pathlib import Path

import pytest
import serial

from bridges import ab3418 as a
from master.run.cosim import CoSimulation
from master.errors import ScenarioError
from master.hooks import Hook
from master.scenario.loader import load_scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = ROOT / "scenarios" / "intersection_signal.toml"
CHAR = 10 / 9600  # ANCHORS S1, 9600 8N1
T2 = 0.010


@pytest.fixture(scope="session")
def tlc_fmu() -> Path:
    from fmus.builder import build_all

    (result,) = build_all(ROOT / "build" / "fmus", only=["TrafficLightController"])
    return result.path


def start_run(run_dir: Path, stop: float = 1.0, mode: str = "lockstep", front=None, **serial_options):
    """A run of the signal scenario in a thread; `front`: a hook stepped before all of the scenario's (where
    the apps' tick is)."""
    sc = load_scenario(SCENARIO)
    sc.time.stop, sc.time.mode = stop, mode
    spec = sc.serial["tlc"]
    spec.connect_timeout = 10.0
    for key, value in serial_options.items():
        setattr(spec, key, value)
    for name in ("err_garbage", "err_oversize", "err_unknown_type", "err_truncated", "responses_sent"):
        sc.record.append(("tlc", name))
    cosim = CoSimulation(sc, run_dir, quiet=True)
    if front is not None:
        cosim.hooks = lambda: [front] + CoSimulation.hooks(cosim)
    results = []
    thread = threading.Thread(target=lambda: results.append(cosim.run()), daemon=True)
    thread.start()
    assert cosim.serial.ready.wait(30), "the serial port never opened"
    return cosim, thread, results


def finish(thread, results):
    thread.join(60)
    assert not thread.is_alive(), "the run did not end"
    (result,) = results
    assert result.status == "completed", result.error
    return result


def events(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "serial-tlc.jsonl").read_text().splitlines()]


def exchanges(evs: list[dict]) -> list[tuple[float, float, float, bytes]]:
    """(request time, answer delivered at, answer's last byte off the line, answer bytes) per request."""
    out, current = [], None
    for e in evs:
        if e["event"] == "rx":
            current = [e["t"], None, None, b""]
            out.append(current)
        elif e["event"] == "tx":
            current[1], current[2] = e["t"], e["wire_end"]
            current[3] += bytes.fromhex(e["hex"])
            assert e["last_rx_t"] == current[0]
    return [tuple(x) for x in out]


def poll_twice(url: str, pause: float = 0.0) -> tuple[bytes, bytes]:
    with serial.serial_for_url(url, timeout=10) as port:
        time.sleep(pause)
        port.write(a.request(a.GET_LONG_STATUS8))
        long_answer = port.read(40)
        time.sleep(pause)
        port.write(a.request(a.GET_SHORT_STATUS))
        short_answer = port.read(11)
    return long_answer, short_answer


def test_S7_round_trip_from_a_pyserial_client_through_the_bridge(tmp_path, tlc_fmu):
    """ANCHORS S7: GetLongStatus8 at 9600 8N1, request 8 B + answer 40 B = 50.0 ms of wire time plus the
    controller turnaround T2 = 10 ms, measured in simulated time from the bridge's log."""
    cosim, thread, results = start_run(tmp_path / "run")
    long_answer, short_answer = poll_twice(cosim.serial.urls["tlc"])
    result = finish(thread, results)

    (frame,) = a.FrameDecoder().feed(long_answer)
    assert frame.msg_type == 0xCC and len(long_answer) == 40
    status = a.LongStatus8.decode(frame.data)
    assert (status.phase_a, status.phase_b, status.greens) == (2, 6, 0b00100010)
    assert a.FrameDecoder().feed(short_answer)[0] == a.Frame(0x05, a.CTRL_UI, 0xC4, bytes([0x22, 0, 1]))

    (t1, delivered1, end1, bytes1), (t2, delivered2, end2, bytes2) = exchanges(events(tmp_path / "run"))
    assert (bytes1, bytes2) == (long_answer, short_answer)  # what the FMU sent is what the client got
    wire1 = (8 + 40) * CHAR
    assert wire1 == pytest.approx(0.0500, abs=1e-12)
    assert t1 == 0.0  # sync = turn: the first poll enters at the first communication point
    assert end1 - t1 == pytest.approx(wire1 + T2, abs=1e-9)                 # 60.0 ms
    assert end2 - t2 == pytest.approx((8 + 11) * CHAR + T2, abs=1e-9)       # 29.8 ms
    # delivered at the communication point that ends the step holding the last stop bit (h = 10 ms) ...
    assert end1 <= delivered1 + 1e-9 < end1 + 0.01
    # ... and the next poll enters right there: the client's own processing costs no simulated time
    assert t2 == pytest.approx(delivered1, abs=1e-9)
    stats = result.metadata["serial"]["tlc"]
    assert stats["bytes_to_fmu"] == 16 and stats["bytes_to_client"] == 51 and stats["clients"] == 1


def test_turn_sync_makes_simulated_times_independent_of_the_client_pace(tmp_path, tlc_fmu):
    """The same polls from a client that dawdles 0.3 s of wall time before each write give the same
    simulated exchange times (sync = "turn" is deterministic in simulated time)."""
    runs = []
    for name, pause in (("fast", 0.0), ("slow", 0.3)):
        cosim, thread, results = start_run(tmp_path / name)
        answers = poll_twice(cosim.serial.urls["tlc"], pause)
        finish(thread, results)
        runs.append((answers, [(t, d, e) for t, d, e, _ in exchanges(events(tmp_path / name))]))
    assert runs[0] == runs[1]


def test_turn_sync_the_clients_next_request_is_in_before_the_next_step_begins(tmp_path, tlc_fmu):
    """The apps' tick goes out at the start of a step, on another socket than the answer's bytes. So that an
    app has the answer in hand at the tick of the step after it, the master waits for the client's next
    request (written once it has read the answer) before it starts that step: a client that dawdles 0.3 s
    after reading an answer has written before the step its request enters begins."""
    begun: list[tuple[float, float]] = []  # (t, wall) of every step's start

    class StepStarts(Hook):
        name = "step_starts"

        def before_step(self, k, t):
            begun.append((t, time.monotonic()))

    cosim, thread, results = start_run(tmp_path / "run", front=StepStarts())
    with serial.serial_for_url(cosim.serial.urls["tlc"], timeout=10) as port:
        port.write(a.request(a.GET_LONG_STATUS8))
        answer = port.read(40)
        time.sleep(0.3)
        written = time.monotonic()
        port.write(a.request(a.GET_LONG_STATUS8))
        port.read(40)
    finish(thread, results)
    assert len(answer) == 40
    (_, delivered, _, _), (t2, _, _, _) = exchanges(events(tmp_path / "run"))[:2]
    assert t2 == pytest.approx(delivered, abs=1e-9)
    (start,) = [wall for t, wall in begun if abs(t - t2) < 1e-9]
    assert start >= written, f"the step at {t2} s began {written - start:.3f} s before the client wrote"


def test_realtime_free_sync_round_trip(tmp_path, tlc_fmu):
    """Realtime (HIL) mode: the master never waits; the poll enters at the next communication point
    after it arrived, and its simulated round trip is still the wire time + turnaround."""
    cosim, thread, results = start_run(tmp_path / "run", stop=1.0, mode="realtime")
    with serial.serial_for_url(cosim.serial.urls["tlc"], timeout=5) as port:
        port.write(a.request(a.GET_LONG_STATUS8))
        answer = port.read(40)
    result = finish(thread, results)
    assert a.FrameDecoder().feed(answer)[0].msg_type == 0xCC
    assert result.metadata["serial"]["tlc"]["sync"] == "free"
    ((t1, delivered, end, _),) = exchanges(events(tmp_path / "run"))
    assert end - t1 == pytest.approx(48 * CHAR + T2, abs=1e-9)


def test_bad_input_through_the_bridge_is_counted_and_the_run_completes(tmp_path, tlc_fmu):
    cosim, thread, results = start_run(tmp_path / "run", stop=2.0)
    with serial.serial_for_url(cosim.serial.urls["tlc"], timeout=10) as port:
        good = a.request(a.GET_SHORT_STATUS)
        port.write(b"\x00\xff\x13" + good[:-2] + bytes([good[-2] ^ 1, 0x7E])  # garbage, FCS error
                   + bytes([0x7E, 0x05, 0x13, 0xC0, 0x84]) + bytes(400) + b"\x7e"   # oversize
                   + bytes.fromhex("0513C07E")                                      # truncated
                   + a.request(0x8E)[1:])                                           # unknown type
        error_answer = port.read(10)
        port.write(good)
        answer = port.read(11)
    result = finish(thread, results)
    assert a.FrameDecoder().feed(error_answer) == [a.Frame(0x05, a.CTRL_UI, 0xEE, bytes([a.ERR_NO_SUCH_NAME, 0]))]
    assert a.FrameDecoder().feed(answer)[0].msg_type == 0xC4
    import csv

    with open(result.run_dir / "timeseries.csv", newline="") as f:
        last = list(csv.DictReader(f))[-1]
    counts = {k.split(".")[1]: int(float(v)) for k, v in last.items() if k.startswith("tlc.err_")}
    assert counts == {"err_fcs": 1, "err_garbage": 1, "err_oversize": 1, "err_unknown_type": 1, "err_truncated": 1}
    assert int(float(last["tlc.responses_sent"])) == 2 and int(float(last["tlc.frames_ok"])) == 2


def test_a_silent_client_loses_its_turn_and_cannot_stall_the_run(tmp_path, tlc_fmu):
    cosim, thread, results = start_run(tmp_path / "run", stop=1.0, turn_timeout=0.3)
    with serial.serial_for_url(cosim.serial.urls["tlc"], timeout=1):
        thread.join(30)
    result = finish(thread, results)
    stats = result.metadata["serial"]["tlc"]
    assert stats["turn_timeouts"] == 1 and stats["sync"] == "turn"
    assert [e["event"] for e in events(tmp_path / "run")][:3] == ["listen", "connect", "turn_timeout"]


def test_no_client_the_scenario_runs_free(tmp_path, tlc_fmu):
    sc = load_scenario(SCENARIO)
    sc.time.stop = 5.0
    result = CoSimulation(sc, tmp_path / "run", quiet=True).run()
    assert result.status == "completed", result.error
    assert result.metadata["serial"]["tlc"]["url"].startswith("socket://127.0.0.1:")
    resolved = (tmp_path / "run" / "scenario.resolved.toml").read_text()
    assert "[serial.tlc]" in resolved and 'listen = "socket://127.0.0.1:0"' in resolved


# -- scenario validation ---------------------------------------------------------------------------------
def serial_problems(tmp_path, tlc_fmu, body: str) -> list[str]:
    path = tmp_path / "s.toml"
    text = textwrap.dedent(f"""
        connections = ["b.serial_tx_hex -> a.serial_rx_hex"]
        [time]
        stop = 1.0
        [fmus.a]
        fmu = "{tlc_fmu}"
        [fmus.b]
        fmu = "{tlc_fmu}"
    """) + textwrap.dedent(body)
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    return info.value.problems


def test_serial_section_errors_name_the_key(tmp_path, tlc_fmu):
    problems = serial_problems(tmp_path, tlc_fmu, """
        [serial.one]
        instance = "nope"
        [serial.two]
        instance = "b"
        listen = "tcp://127.0.0.1:80"
        rx = "baud"
        speed = 3
        [serial.three]
        instance = "a"
        [serial.four]
        instance = "b"
        tx = "serial_tx_hexx"
        sync = "sometimes"
        turn_timeout = 0
        [serial.five]
        instance = "b"
        idle = "frames_ok"
    """)
    expected = [
        "serial.one.instance: unknown instance 'nope'",
        "serial.two.speed: unknown key",
        "serial.two.listen: expected \"socket://HOST:PORT\"",
        "serial.two.rx: b.baud is a parameter of type Real; expected a string input",
        "serial.three.rx: a.serial_rx_hex is already driven by b.serial_tx_hex -> a.serial_rx_hex",
        "serial.four.tx: unknown variable b.serial_tx_hexx (did you mean 'serial_tx_hex'",
        "serial.four.sync: expected one of turn, free, got 'sometimes'",
        "serial.four.turn_timeout: must be > 0",
        "serial.five.idle: b.frames_ok is an output of type Integer; expected a boolean output",
        "serial.five.rx: b.serial_rx_hex is already the rx of serial.four",
    ]
    for line in expected:
        assert any(p.startswith(line) for p in problems), (line, problems)
    assert len(problems) == len(expected), problems


def test_serial_top_key_must_be_a_table(tmp_path, tlc_fmu):
    path = tmp_path / "s.toml"
    path.write_text(f'serial = 3\n[time]\nstop = 1.0\n[fmus.a]\nfmu = "{tlc_fmu}"\n')
    with pytest.raises(ScenarioError, match="serial: expected a table of \\[serial.NAME\\] tables"):
        load_scenario(path)
