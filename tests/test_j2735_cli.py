"""`v2i j2735 decode|encode` on the interop vectors, and what bad input does."""
from __future__ import annotations

import io
import json
import subprocess
import sys

import pytest

from master.cli import main
from test_j2735_vectors import BARE, VECTORS


def _decode(capsys, hex_text):
    code = main(["j2735", "decode", hex_text])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("index", [i for i, v in enumerate(VECTORS) if v["message"] in BARE])
def test_decode_then_encode_gives_the_vector_back(capsys, tmp_path, index):
    vector = VECTORS[index]
    code, out, err = _decode(capsys, vector["hex"])
    assert code == 0, err
    document = json.loads(out)
    assert document["messageId"] == BARE[vector["message"]]
    path = tmp_path / "m.json"
    path.write_text(out)
    assert main(["j2735", "encode", str(path)]) == 0
    hex_out = capsys.readouterr().out.strip()
    expected = vector["hex"].upper()
    trailing = document.get("trailingBytes", 0)
    assert hex_out == (expected[:len(expected) - 2 * trailing] if trailing else expected)


def test_decode_reads_stdin_with_spaces_and_prefix(monkeypatch, capsys):
    hex_text = VECTORS[0]["hex"]
    spaced = "0x" + " ".join(hex_text[i:i + 60] for i in range(0, len(hex_text), 60)) + "\n"
    monkeypatch.setattr(sys, "stdin", io.StringIO(spaced))
    assert main(["j2735", "decode", "-", "--compact"]) == 0
    assert json.loads(capsys.readouterr().out)["message"]["coreData"]["msgCnt"] == 88


def test_decode_unwraps_1609dot2(capsys):
    signed = next(v for v in VECTORS if v["message"] == "IEEE1609.2(signed)+BSM")
    code, out, _ = _decode(capsys, signed["hex"])
    document = json.loads(out)
    assert code == 0 and document["ieee1609dot2"]["psid"] == 32 and document["messageId"] == 20
    assert document["ieee1609dot2"]["verified"] is False


def test_unknown_id_prints_the_id_and_octets(capsys):
    other = next(v for v in VECTORS if v["message"].startswith("other (labelled PSM"))
    code, out, _ = _decode(capsys, other["hex"])
    document = json.loads(out)
    assert code == 0 and document["messageId"] == 285 and document["type"] is None and "octets" in document["value"]


@pytest.mark.parametrize("text,reason", [
    ("00zz", "not hex: character 'z'"),
    ("001", "odd number of hex digits"),
    ("0014ff", "MessageFrame"),
    ("", "no bytes"),
])
def test_decode_bad_input_exits_2_with_the_reason(capsys, text, reason):
    code, out, err = _decode(capsys, text)
    assert code == 2 and out == "" and reason in err


@pytest.mark.parametrize("document,reason", [
    ('{"messageId": 20, "message": {"coreData": {}}}', "BasicSafetyMessage"),
    ('{"messageId": "BSM", "message": {}}', "messageId: expected an integer"),
    ('{"messageId": 20}', "neither 'message' nor 'value'"),
    ('[1, 2]', "must be an object"),
    ('{"messageId": 99, "message": {}}', "messageId 99"),
    ('{"messageId": 41, "value": {"octets": "zz"}}', "value.octets"),
    ('{not json', "not JSON"),
])
def test_encode_bad_json_names_the_problem(tmp_path, capsys, document, reason):
    path = tmp_path / "bad.json"
    path.write_text(document)
    assert main(["j2735", "encode", str(path)]) == 2
    assert reason in capsys.readouterr().err


def test_encode_a_range_error_names_the_field(tmp_path, capsys):
    main(["j2735", "decode", VECTORS[0]["hex"]])
    document = json.loads(capsys.readouterr().out)
    document["message"]["coreData"]["lat"] = 950000000
    path = tmp_path / "m.json"
    path.write_text(json.dumps(document))
    assert main(["j2735", "encode", str(path)]) == 2
    err = capsys.readouterr().err
    assert "lat" in err and "out of range" in err


def test_missing_file_exits_2(capsys, tmp_path):
    assert main(["j2735", "encode", str(tmp_path / "none.json")]) == 2


def test_the_installed_command_runs():
    result = subprocess.run([sys.executable, "-m", "master.cli", "j2735", "decode", VECTORS[0]["hex"], "--compact"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["messageId"] == 20
