"""SPaT and MAP from the RSU app as a process: the controller polled over AB3418, the MAP from the layout.

`scenarios/intersection_signal.toml` (the case study's fixed-time 2-phase plan,
AB3418 port at 9600 8N1) with a `[world]` naming the intersection and four
signal heads, cut to 35 s so the north-south greens end (25.5 s) and the
east-west greens start (30 s). The app opens the controller's port from
V2I_SERIAL_TLC like a box opens /dev/ttyS0. Ground truth: the controller's
state_k / min_end_k outputs in timeseries.csv and the serial log.

A second test gives the app a controller of its own (a socket in this process)
that answers a few polls, sends a broken frame and then falls silent.
"""
from __future__ import annotations

import csv
import json
import socket
import threading
import uuid

import numpy as np
import pytest

from bridges import ab3418
from bridges.j2735 import default_codec
from bridges.j2735.map import MapData
from bridges.j2735.spat import PHASE_STATES, Spat
from bridges.security import PSID_SPAT_MAP, Verifier, load_certificate, time64_us

from test_rsu_app_support import (ROOT, app_summary, bridge_tables, free_port, make_pki, probe_table, rsu_table,
                                  run_with_probe)

STOP = 35.0
SIGNALS = """
[world.intersection]
road_width = 7.0
lane_width = 3.5
arm_length = 120.0
sidewalk_width = 2.0
[[world.signals]]
name = "nb_head"
x = 5.0
y = 5.0
yaw = 270.0
signal_group = 2
[[world.signals]]
name = "sb_head"
x = -5.0
y = -5.0
yaw = 90.0
signal_group = 6
[[world.signals]]
name = "eb_head"
x = 5.0
y = -5.0
yaw = 180.0
signal_group = 8
[[world.signals]]
name = "wb_head"
x = -5.0
y = 5.0
yaw = 0.0
signal_group = 4
"""


def signal_scenario(prefix: str, port: int) -> str:
    text = (ROOT / "scenarios" / "intersection_signal.toml").read_text()
    text = text.replace("stop = 120.0", f"stop = {STOP}")
    text = text.replace('listen = "socket://127.0.0.1:0"', 'listen = "socket://127.0.0.1:0"\ncollect_gap = 0.005')
    assert f"stop = {STOP}" in text and "collect_gap" in text
    return (text + SIGNALS + bridge_tables(prefix, port) + probe_table()
            + rsu_table("rsu", "--pki-dir", "keys", "--set", "camera.names=",
                        latencies="{ encode = 0.001, sign = 0.001 }"))


@pytest.fixture(scope="module")
def signal_run(tmp_path_factory, fmu_dir):
    folder = tmp_path_factory.mktemp("rsu-spat")
    keys = make_pki(folder / "keys", {"rsu": "0x7f,0x82"})
    prefix, port = f"test/rsu-spat-{uuid.uuid4().hex[:8]}", free_port()
    result, probe, out = run_with_probe(signal_scenario(prefix, port), folder, prefix, port)
    assert result.returncode == 0, result.stdout + result.stderr
    verifier = Verifier([load_certificate(keys / "v2i-scenario-ca.cert")])
    epoch = probe.world["epoch_unix_s"]
    spats, maps = [], []
    for s in probe.sent:
        verified = verifier.verify(s.payload, time64_us(epoch + s.t_sim))  # every frame: signed by the CA's rsu
        assert verified.psid == PSID_SPAT_MAP and verified.signer == "rsu"
        frame = default_codec().decode(verified.payload)
        if frame.message_id == 19:
            spats.append((s.t_sim, Spat.from_asn1(frame.message)))
        elif frame.message_id == 18:
            maps.append((s.t_sim, MapData.decode(verified.payload)))
    rows = list(csv.DictReader(open(out / "timeseries.csv")))
    serial = [json.loads(line) for line in (out / "serial-tlc.jsonl").read_text().splitlines()]
    return {"out": out, "spats": spats, "maps": maps, "rows": rows, "serial": serial, "epoch": epoch,
            "summary": app_summary(out, "rsu"), "meta": json.loads((out / "metadata.json").read_text())}


def _truth(rows):
    t = np.array([float(r["time"]) for r in rows])
    states = {g: np.array([int(float(r[f"tlc.state_{g}"])) for r in rows]) for g in (2, 4, 6, 8)}
    return t, states


def _serial_timing(serial) -> tuple[float, float]:
    """(longest request-to-answer round trip, longest gap between answers), simulated s, from the serial log."""
    trips = [e["wire_end"] - e["last_rx_t"] for e in serial if e["event"] == "tx" and "last_rx_t" in e]
    ends = [e["wire_end"] for e in serial if e["event"] == "tx"]
    return max(trips), float(np.max(np.diff(ends)))


def test_the_app_polls_the_controller_back_to_back_over_the_serial_link(signal_run):
    link = signal_run["summary"]["controller_link"]
    assert link["connected"] and not link["lost"] and link.get("timeouts", 0) == 0
    assert not any(k.startswith("bad_frame") for k in link)
    round_trip, gap = _serial_timing(signal_run["serial"])
    # GetLongStatus8 at 9600 8N1: 8 + 40 bytes on the wire and the 10 ms turnaround (ANCHORS S7)
    assert 0.055 < round_trip < 0.075, round_trip
    assert gap < round_trip + 0.025, gap  # the next request follows the answer at the next step
    assert link["answers"] > STOP / (round_trip + 0.02) * 0.9
    serial_meta = signal_run["meta"]["serial"]["tlc"]
    assert serial_meta["turn_timeouts"] == 0


def test_spat_follows_the_controller_within_one_serial_round_trip(signal_run):
    spats, rows = signal_run["spats"], signal_run["rows"]
    t, truth = _truth(rows)
    round_trip, gap = _serial_timing(signal_run["serial"])
    # a SPaT shows the newest answer: built at most one poll before, plus the answer's own time on the wire
    window = gap + 40 * 10 / 9600 + 0.01
    assert len(spats) == pytest.approx(STOP * 10, abs=3)  # 10 Hz from the first answer on
    for t_s, spat in spats:
        shown = {m.signal_group: PHASE_STATES.index(m.state) for m in spat.intersections[0].movements}
        assert set(shown) == {2, 4, 6, 8}
        lo, hi = np.searchsorted(t, t_s - window - 1e-9), np.searchsorted(t, t_s + 1e-9)
        candidates = {tuple(int(truth[g][i]) for g in (2, 4, 6, 8)) for i in range(max(lo - 1, 0), hi)}
        assert tuple(shown[g] for g in (2, 4, 6, 8)) in candidates, (t_s, shown, candidates)
    # and every change of the controller shows within that window and one SPaT period
    for g in (2, 4, 6, 8):
        changes = [t[i] for i in range(1, len(t)) if truth[g][i] != truth[g][i - 1]]
        assert changes, g
        for c in changes:
            state = truth[g][np.searchsorted(t, c)]
            seen = [t_s for t_s, spat in spats if t_s >= c and any(
                m.signal_group == g and PHASE_STATES.index(m.state) == state for m in spat.intersections[0].movements)]
            assert seen and seen[0] - c <= window + 0.1 + 1e-6, (g, c, seen[:1])


def test_spat_time_marks_are_the_controllers_times_to_change(signal_run):
    spats, rows, epoch = signal_run["spats"], signal_run["rows"], signal_run["epoch"]
    t = np.array([float(r["time"]) for r in rows])
    min_end_2 = np.array([float(r["tlc.min_end_2"]) for r in rows])
    round_trip, gap = _serial_timing(signal_run["serial"])
    window = gap + 40 * 10 / 9600 + 0.01  # how old the status behind a SPaT may be (see the test above)
    checked = 0
    for t_s, spat in spats:
        m2 = next(m for m in spat.intersections[0].movements if m.signal_group == 2)
        if m2.state != "protected-Movement-Allowed" or m2.min_end_s is None:
            continue
        lo, hi = np.searchsorted(t, t_s - window - 1e-9), np.searchsorted(t, t_s + 1e-9)
        # the controller's earliest change as J2735 time marks (seconds in the UTC hour), over that window
        expected = [(epoch + e) % 3600.0 for e in min_end_2[max(lo - 1, 0):hi] if e >= 0]
        error = min(abs((m2.min_end_s - x + 1800) % 3600 - 1800) for x in expected)
        assert error <= 0.15, (t_s, m2.min_end_s, expected)  # tenths of a second, and the link's timing
        checked += 1
    assert checked > 100


def test_map_describes_the_intersection_of_the_scenario(signal_run):
    maps = signal_run["maps"]
    assert len(maps) == pytest.approx(STOP, abs=1)  # 1 Hz
    g = maps[-1][1].intersections[0]
    assert (g.ref_latitude, g.ref_longitude) == pytest.approx((42.2808, -83.743))  # the world's origin
    assert g.lane_width == 3.5 and len(g.lanes) == 8
    assert {l.lane_id: l.signal_group() for l in g.lanes if l.ingress} == {11: 2, 21: 8, 31: 6, 41: 4}
    stop_lines = {l.lane_id: l.stop_line for l in g.lanes if l.ingress}
    assert stop_lines[11] == pytest.approx((1.75, -4.5)) and stop_lines[21] == pytest.approx((-4.5, -1.75))
    assert stop_lines[31] == pytest.approx((-1.75, 4.5)) and stop_lines[41] == pytest.approx((4.5, 1.75))
    assert all(abs(n.x) <= 120 and abs(n.y) <= 120 for l in g.lanes for n in l.nodes)


# -- a controller that stops answering ------------------------------------------------------------------
class FlakyController:
    """A TCP 'serial port' that answers `answers` GetLongStatus8 polls, sends one broken frame, then is silent."""

    def __init__(self, answers: int):
        self.answers = answers
        self.server = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.server.getsockname()[1]}"
        self.polls = 0
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        conn, _ = self.server.accept()
        decoder = ab3418.FrameDecoder()
        status = ab3418.LongStatus8(greens=0b10, pattern=1, phase_a=2, phase_b=6, ttc_a_min=100, ttc_a_max=150)
        answered = 0
        with conn:
            while True:
                try:
                    data = conn.recv(256)
                except OSError:
                    return
                if not data:
                    return
                for frame in decoder.feed(data):
                    if not isinstance(frame, ab3418.Frame):
                        continue
                    self.polls += 1
                    if answered < self.answers:
                        conn.sendall(ab3418.encode_frame(1, ab3418.response_type(frame.msg_type), status.encode()))
                        answered += 1
                    elif answered == self.answers:  # a whole answer whose FCS is wrong
                        body = bytes((ab3418.station_address(1), ab3418.CTRL_UI, ab3418.IPI,
                                      ab3418.response_type(frame.msg_type))) + status.encode()
                        fcs = bytes(b ^ 0x01 for b in ab3418.fcs_bytes(body))
                        conn.sendall(b"\x7e" + ab3418.stuff(body + fcs) + b"\x7e")
                        answered += 1

    def close(self) -> None:
        self.server.close()


def test_a_controller_that_stops_answering_stops_the_spat_without_a_crash(tmp_path, fmu_dir):
    controller = FlakyController(answers=20)
    keys = make_pki(tmp_path / "keys", {"rsu": "0x7f,0x82"})
    prefix, port = f"test/rsu-flaky-{uuid.uuid4().hex[:8]}", free_port()
    text = f"""
[scenario]
name = "rsu_flaky_controller"
[time]
stop = 20.0
step = 0.01
[fmus.car]
fmu = "VehicleDynamics"
""" + bridge_tables(prefix, port) + probe_table() + rsu_table(
        "rsu", "--pki-dir", "keys", "--set", "camera.names=", "--serial-url", controller.url,
        "--set", "spat.answer_timeout_s=0.2", latencies="{ encode = 0.001, sign = 0.001 }")
    try:
        result, probe, out = run_with_probe(text, tmp_path, prefix, port)
    finally:
        controller.close()
    assert result.returncode == 0, result.stdout + result.stderr
    summary = app_summary(out, "rsu")
    link = summary["controller_link"]
    assert link["answers"] == 20 and link["bad_frame_fcs"] == 1, link
    assert link["timeouts"] >= 1 and controller.polls > 21, (link, controller.polls)
    spats = [s.t_sim for s in probe.sent if s.key == "v2x/tx/rsu"]
    assert spats, "no SPaT while the controller answered"
    # no stale SPaT: none later than max_age (0.5 s) after the last answer arrived
    assert summary["spat"]["suppressed_stale"] > 10 * (20.0 - max(spats)) * 0.9
    assert max(spats) < 20.0 - 1.0
    assert summary["exit"].startswith("the run ended") and summary["notes"] == ["no MAP: the master's join reply "
                                                                               "describes no intersection (the "
                                                                               "scenario has no [world])"]
