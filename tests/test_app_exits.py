"""Every app ends a session the master refused, never answered or lost with the same exit code and reason
(bridges.timesync.exits), checked here as a process for the RSU app and the attacker with no master running."""
from __future__ import annotations

import json
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from bridges.timesync.errors import JoinTimeout, MasterLost, Refused
from bridges.timesync.exits import EXIT_MASTER_LOST, EXIT_NO_MASTER, EXIT_REFUSED, session_end
from test_rsu_app_support import free_port, make_pki

ROOT = Path(__file__).resolve().parent.parent


def test_each_session_error_has_its_code_and_reason():
    assert session_end(Refused("rsu", "name taken")) == (EXIT_REFUSED, "refused: name taken")
    assert session_end(JoinTimeout(["rsu"], 2.0)) == (EXIT_NO_MASTER, "no welcome from the master")
    lost = MasterLost("nothing from the master for 80 s")
    assert session_end(lost) == (EXIT_MASTER_LOST, str(lost))
    with pytest.raises(TypeError):
        session_end(ValueError("not one of them"))


@pytest.mark.parametrize("app, args", [
    ("rsu_app", ["--config", str(ROOT / "scenarios" / "apps" / "rsu.toml")]),
    ("attacker", ["--config", str(ROOT / "scenarios" / "apps" / "attacker.toml")]),
])
def test_an_app_with_no_master_exits_4_saying_so(app, args, tmp_path):
    pytest.importorskip("zenoh")
    keys = make_pki(tmp_path / "keys", {"rsu": "0x7f,0x82", "cav": "0x20"})  # a fresh clone has none
    stolen = ["--stolen-dir", str(tmp_path / "stolen")] if app == "attacker" else []
    argv = [sys.executable, "-m", app, *args, "--pki-dir", str(keys), *stolen, "--bus", "zenoh", "--prefix", f"test/exit-{uuid.uuid4().hex[:8]}",
            "--connect", f"tcp/127.0.0.1:{free_port()}", "--join-timeout", "1.5"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == EXIT_NO_MASTER, proc.stdout + proc.stderr
    assert f"{app}: " in proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["exit"] == "no welcome from the master"
