"""The emulated RSU box (bridges.rsu_box): its core in-process, then the real process on loopback.

The process test sends Immediate Forward records and garbage to a box started with
`python -m bridges.rsu_box`, receives what it forwards on two "OBU" sockets, and checks the delay it
was given, the loss rate, the refusals by reason in its log and summary, and a clean exit on SIGTERM.
Everything goes to 127.0.0.1 only.
"""
from __future__ import annotations

import json
import select
import signal
import socket
import subprocess
import sys
import time
from datetime import datetime, timedelta, timezone

import pytest

from bridges import immediate_forward as imf
from bridges.rsu_box import BoxCore, BoxSettings, main as box_main, on_the_air, BoxRefusal
from bridges.security import PSID_BSM, PSID_SPAT_MAP, PSID_SURROGATE_BSM, ScenarioCA, Signer, oer, time64_us
from bridges.udp_endpoint import Endpoint
from test_immediate_forward import BSM, MAP, SPAT

OBU = [Endpoint("127.0.0.1", 9), Endpoint("127.0.0.1", 10)]  # the core sends nothing: any address


@pytest.fixture(scope="module")
def signer():
    start = datetime.now(timezone.utc) - timedelta(hours=1)  # valid from an hour before now
    ca = ScenarioCA.create(start=start)
    return Signer(ca.issue("rsu", [PSID_BSM, PSID_SURROGATE_BSM, PSID_SPAT_MAP], start=start))


def _now_us() -> int:
    return time64_us(datetime.now(timezone.utc).timestamp())


# -- the core ---------------------------------------------------------------------------------------------------
def test_what_goes_on_the_emulated_air(signer):
    signed = signer.sign(BSM, PSID_SURROGATE_BSM, _now_us())
    air = on_the_air(imf.Record("BSM", 0x7F, signed), imf.DEFAULT_ROUTES)
    assert air.envelope == signed and air.frame == BSM and air.signed  # 1609.2 data goes as it is
    air = on_the_air(imf.Record("SPAT", 0x8002, SPAT, signature=True), imf.DEFAULT_ROUTES)
    assert air.envelope == oer.unsecured(SPAT) and air.frame == SPAT and not air.signed  # a bare frame: wrapped
    refusals = [
        (imf.Record("SPAT", 0x8002, MAP), "type-mismatch"),
        (imf.Record("BSM", 0x20, signed), "psid-mismatch"),  # signed for 0x7F, sent as 0x20
        (imf.Record("SPAT", 0x8002, SPAT, encryption=True), "encryption-not-emulated"),
        (imf.Record("SPAT", 0x8002, b"\x80"), "payload-not-j2735"),
    ]
    for record, reason in refusals:
        with pytest.raises(BoxRefusal) as info:
            on_the_air(record, imf.DEFAULT_ROUTES)
        assert info.value.reason == reason, record


def test_core_delays_loses_by_seed_and_counts_refusals_by_reason():
    def run(seed):
        events = []
        core = BoxCore(BoxSettings(OBU, delay_s=0.02, jitter_s=0.005, loss=0.3, seed=seed, obu_format="bare"),
                       events.append)
        sends = []
        for i in range(200):
            sends += core.receive(imf.write(imf.Record("BSM", 0x20, BSM)), "127.0.0.1:5000", now=i * 0.1)
        for data in (b"garbage", imf.write(imf.Record("SPAT", 0x8002, MAP)),
                     b"Version=0.7\nType=SPAT\nPSID=0x20\nPayload=0013\n"):
            assert core.receive(data, "127.0.0.1:5000", now=99.0) == []
        return core, sends, events

    core, sends, events = run(5)
    assert core.counts["received"] == 203 and core.counts["accepted"] == 200 and core.counts["refused"] == 3
    assert dict(core.refused) == {"malformed-line": 1, "type-mismatch": 1, "wrong-psid": 1}
    lost = core.counts["lost"]
    assert len(sends) + lost == 400 and 0.3 * 400 - 3 * 9.2 < lost < 0.3 * 400 + 3 * 9.2  # binomial, 3 sigma
    assert all(0.02 <= due - n * 0.1 <= 0.025 + 1e-9 for due, _, out, n in sends)
    assert all(out == BSM for _, _, out, _ in sends)
    assert {t for _, t, _, _ in sends} == set(OBU)  # each receiver draws on its own
    assert [e["reason"] for e in events if e["event"] == "refused"] == ["malformed-line", "type-mismatch", "wrong-psid"]
    again, sends_again, _ = run(5)
    assert sends_again == sends  # the same seed loses the same records, with the same jitter
    _, sends_other, _ = run(6)
    assert sends_other != sends


# -- the process ----------------------------------------------------------------------------------------------------
def _start_box(*args: str) -> tuple[subprocess.Popen, Endpoint]:
    proc = subprocess.Popen([sys.executable, "-m", "bridges.rsu_box", "--listen", "127.0.0.1:0", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ready, _, _ = select.select([proc.stdout], [], [], 30)
    assert ready, "the box did not say where it listens"
    first = json.loads(proc.stdout.readline())
    assert first["event"] == "listening", first
    host, port = first["address"].rsplit(":", 1)
    return proc, Endpoint(host, int(port))


def _obu_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    return sock


def test_box_process_forwards_after_its_delay_loses_at_its_rate_and_counts_garbage(tmp_path, signer):
    obus = [_obu_socket(), _obu_socket()]
    forwards = [f"127.0.0.1:{s.getsockname()[1]}" for s in obus]
    log = tmp_path / "box.jsonl"
    delay_ms, loss, n = 40.0, 0.2, 120
    proc, address = _start_box("--forward", forwards[0], "--forward", forwards[1], "--delay-ms", str(delay_ms),
                               "--loss", str(loss), "--seed", "3", "--obu-format", "ieee1609dot2", "--log", str(log))
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent_at: dict[bytes, float] = {}
    got: list[list[tuple[bytes, float]]] = [[], []]

    def collect(until: float) -> None:
        while True:
            left = until - time.monotonic()
            ready, _, _ = select.select(obus, [], [], max(0.0, left))
            now = time.monotonic()
            for i, sock in enumerate(obus):
                if sock in ready:
                    got[i].append((sock.recv(65536), now))
            if not ready and left <= 0:
                return

    try:
        kinds = [("BSM", 0x7F, BSM, PSID_SURROGATE_BSM), ("SPAT", 0x8002, SPAT, PSID_SPAT_MAP),
                 ("MAP", 0x8002, MAP, PSID_SPAT_MAP)]
        garbage = [b"\x00\x01\x02", b"Version=0.7\nType=BSM\nPSID=0x20\nPayload=001", b"x" * 9000,
                   imf.write(imf.Record("SSM", 0xE0000015, BSM)), b"Version=0.7\nType=SPAT\nPSID=0x20\nPayload=0013\n"]
        for i in range(n):
            typ, psid, frame, envelope_psid = kinds[i % 3]
            envelope = signer.sign(frame, envelope_psid, _now_us() + i)  # unique bytes per record
            sent_at[envelope] = time.monotonic()
            tx.sendto(imf.write(imf.Record(typ, psid, envelope)), (address.host, address.port))
            if i % 24 == 0:
                tx.sendto(garbage[i // 24], (address.host, address.port))
            collect(time.monotonic() + 0.004)
        collect(time.monotonic() + 0.5)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
        tx.close()
        for sock in obus:
            sock.close()
    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["event"] == "summary"
    assert summary["received"] == n + 5 and summary["accepted"] == n and summary["refused"] == 5
    assert summary["refused_by_reason"] == {"oversize": 1, "payload-not-hex": 1, "type-mismatch": 1,
                                            "malformed-line": 1, "wrong-psid": 1}, summary
    received = [d for per_obu in got for d in per_obu]
    assert summary["forwarded"] == len(received) and summary["lost"] + len(received) == 2 * n
    sigma = (2 * n * loss * (1 - loss)) ** 0.5
    assert abs(summary["lost"] - 2 * n * loss) < 3 * sigma, summary
    for per_obu in got:
        assert len({data for data, _ in per_obu}) == len(per_obu)  # no duplicates
        for data, at in per_obu:
            assert data in sent_at, "forwarded bytes are not the 1609.2 data that was sent"
            assert at - sent_at[data] >= delay_ms / 1e3, (at - sent_at[data])
    delays = sorted(at - sent_at[data] for data, at in received)
    assert delays[len(delays) // 2] < delay_ms / 1e3 + 0.02, delays[len(delays) // 2]  # the delay, not more
    events = [json.loads(line) for line in log.read_text().splitlines()]
    kinds_logged = {e["event"] for e in events}
    assert {"received", "refused", "forwarded", "lost", "summary"} <= kinds_logged
    assert sum(e["event"] == "forwarded" for e in events) == len(received)
    assert all(e["delay_ms"] >= delay_ms for e in events if e["event"] == "forwarded")


def test_box_refuses_bad_arguments_with_every_problem(capsys):
    code = box_main(["--listen", "127.0.0.1", "--forward", "nowhere", "--loss", "2", "--psid", "mapp=0x8002"])
    assert code == 2
    err = capsys.readouterr().err
    for word in ("--listen", "--forward", "--loss", "--psid mapp"):
        assert word in err, err
