"""`v2i j2735 decode --trust DIR` as a process: the verdict, the signer and the reason; exit statuses; pipes.

Exit status: 0 decoded (and, with --trust, verified), 1 decoded but the envelope refused, 2 bad input, 141
the reader of stdout went away.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from datetime import datetime, timedelta, timezone

import pytest

from bridges.j2735.bsm import surrogate_bsm
from bridges.security import PSID_SURROGATE_BSM, ScenarioCA, Signer, to_time64
from bridges.security import oer

NOW = datetime.now(timezone.utc)
NOW_US = to_time64(NOW)
START = NOW - timedelta(hours=1)
BSM = surrogate_bsm(3, b"salt", latitude=42.0, longitude=-83.0, speed=10.0, heading=90.0).encode()


def v2i(*args: str, stdin: str | None = None, stdout=subprocess.PIPE) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "master.cli", "j2735", *args], input=stdin, stdout=stdout,
                          stderr=subprocess.PIPE, text=True, check=False, timeout=120)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A trust store laid out as `v2i pki init` writes it, valid from an hour ago."""
    directory = tmp_path_factory.mktemp("keys")
    ca = ScenarioCA.create(start=START)
    ca.credentials.save(directory)
    station = ca.issue("rsu1", [PSID_SURROGATE_BSM, 0x82], start=START)
    station.save(directory)
    return directory, station


def _decode_trusted(directory, data: bytes, *extra: str):
    result = v2i("decode", data.hex(), "--trust", str(directory), "--compact", *extra)
    document = json.loads(result.stdout) if result.stdout else None
    return result, document


@pytest.mark.parametrize("mode", ["digest", "certificate"])
def test_a_genuine_frame_verifies_and_names_its_signer(store, mode):
    directory, station = store
    data = Signer(station, signer_identifier=mode).sign(BSM, PSID_SURROGATE_BSM, NOW_US)
    result, document = _decode_trusted(directory, data)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    verification = document["verification"]
    assert (verification["verdict"], verification["signer"]) == ("accepted", "rsu1")
    assert document["ieee1609dot2"]["verified"] is True and document["messageId"] == 20


def test_a_frame_from_another_ca_is_refused_with_the_reason(store):
    directory, _ = store
    impostor = ScenarioCA.create(start=START).issue("rsu1", [PSID_SURROGATE_BSM], start=START)
    result, document = _decode_trusted(directory, Signer(impostor).sign(BSM, PSID_SURROGATE_BSM, NOW_US))
    assert result.returncode == 1
    assert document["verification"]["verdict"] == "rejected"
    assert document["verification"]["reason"] == "untrusted-signer"
    assert document["verification"]["signer"] == "rsu1"  # what the frame claims
    assert document["ieee1609dot2"]["verified"] is False and document["messageId"] == 20  # still decoded
    assert result.stderr.count("\n") == 1 and "envelope refused: untrusted-signer" in result.stderr


@pytest.mark.parametrize("attack, reason", [("signature", "bad-signature"), ("trailing", "trailing-bytes")])
def test_a_tampered_frame_is_refused_with_its_reason(store, attack, reason):
    directory, station = store
    data = Signer(station, signer_identifier="digest").sign(BSM, PSID_SURROGATE_BSM, NOW_US)
    if attack == "signature":
        envelope = oer.decode("Ieee1609Dot2Data", data)
        signature = envelope["content"][1]["signature"][1]
        signature["sSig"] = bytes([signature["sSig"][0] ^ 1]) + signature["sSig"][1:]
        data = oer.encode("Ieee1609Dot2Data", envelope)
    else:
        data += b"\x00"
    result, document = _decode_trusted(directory, data)
    assert result.returncode == 1 and document["verification"]["reason"] == reason
    assert document["verification"]["signer"] == "rsu1"  # the store knows whose digest it is
    assert "Traceback" not in result.stderr


def test_the_receiver_clock_is_the_generation_time_unless_told(store):
    directory, station = store
    old = NOW_US - 30 * 10**6
    data = Signer(station).sign(BSM, PSID_SURROGATE_BSM, old)
    result, document = _decode_trusted(directory, data)
    assert result.returncode == 0 and document["verification"]["checkedAt"].startswith(
        (NOW - timedelta(seconds=30)).strftime("%Y-%m-%dT%H:%M"))
    result, document = _decode_trusted(directory, data, "--at", "now")
    assert result.returncode == 1 and document["verification"]["reason"] == "outside-time-window"


def test_a_bare_message_frame_has_no_envelope_to_verify(store):
    result, document = _decode_trusted(store[0], BSM)
    assert result.returncode == 1 and document["verification"]["reason"] == "unsecured-not-allowed"


def test_the_store_v2i_pki_init_writes_is_what_trust_reads(tmp_path):
    keys = tmp_path / "keys"
    made = subprocess.run([sys.executable, "-m", "master.cli", "pki", "init", str(keys), "--station", "rsu1:0x7f"],
                          capture_output=True, text=True, check=False, timeout=120)
    assert made.returncode == 0, made.stderr
    from bridges.security import load_credentials

    station = load_credentials(keys, "rsu1")
    generated = to_time64(datetime.now(timezone.utc)) + 10**6  # certificates from `pki init` start now
    result, document = _decode_trusted(keys, Signer(station, signer_identifier="digest").sign(
        BSM, PSID_SURROGATE_BSM, generated))
    assert result.returncode == 0, result.stderr
    assert document["verification"]["signer"] == "rsu1"


@pytest.mark.parametrize("args, reason", [
    (["decode", "00zz"], "not hex: character 'z'"),
    (["decode", "0014ff"], "MessageFrame"),
    (["decode", "0014", "--trust", "/nonexistent/keys"], "--trust /nonexistent/keys: trust store"),
    (["decode", "0014", "--trust", "EMPTY"], "no CA certificate"),
    (["decode", BSM.hex(), "--trust", "STORE", "--at", "yesterday"], "--at 'yesterday': expected"),
    (["encode", "-"], "not JSON"),
    (["encode", "MISSING"], "No such file"),
])
def test_bad_input_exits_2_with_one_line_naming_the_reason(store, tmp_path, args, reason):
    substitute = {"EMPTY": str(tmp_path), "STORE": str(store[0]), "MISSING": str(tmp_path / "none.json")}
    result = v2i(*[substitute.get(a, a) for a in args], stdin="{not json")
    assert result.returncode == 2, (result.returncode, result.stderr)
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1 and reason in result.stderr, result.stderr


def test_encode_of_an_invalid_message_exits_2(tmp_path):
    path = tmp_path / "m.json"
    path.write_text('{"messageId": 20, "message": {"coreData": {}}}')
    result = v2i("encode", str(path))
    assert result.returncode == 2 and "BasicSafetyMessage" in result.stderr and "Traceback" not in result.stderr


def test_a_closed_pipe_ends_decode_quietly(store):
    """The reader has gone before the first write (what `| head -1` does to a longer output): no traceback."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = v2i("decode", BSM.hex(), stdout=write_end)
    finally:
        os.close(write_end)
    assert result.returncode == 141
    assert result.stderr == ""


def test_decode_piped_into_head(store):
    command = f"{sys.executable} -m master.cli j2735 decode {BSM.hex()} | head -1"
    result = subprocess.run(["bash", "-c", command], capture_output=True, text=True, check=False, timeout=120)
    assert result.stdout == "{\n" and result.stderr == ""
