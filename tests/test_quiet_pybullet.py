"""master.world.quiet_pybullet: the project's pybullet import prints no banner and loses no output."""
from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("pybullet")

SCRIPT = """
import ctypes, sys
print("py-out before", flush=True)
print("py-err before", file=sys.stderr, flush=True)
ctypes.CDLL(None).printf(b"c-out before\\n")   # buffered in C's stdout: must survive the redirection
{import_line}
print("connected", pb.connect(pb.DIRECT))
print("py-err after", file=sys.stderr)
"""


def _run(import_line: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", SCRIPT.format(import_line=import_line)],
                          capture_output=True, text=True, timeout=120)


def test_plain_import_prints_the_banner():
    """The thing being silenced exists (otherwise the test below would prove nothing)."""
    r = _run("import pybullet as pb")
    assert r.returncode == 0, r.stderr
    assert "pybullet build time" in r.stdout + r.stderr


def test_quiet_import_prints_no_banner_and_keeps_everything_else():
    r = _run("from master.world.quiet_pybullet import pybullet as pb")
    assert r.returncode == 0, r.stderr
    assert "build time" not in r.stdout + r.stderr
    assert r.stdout.splitlines() == ["py-out before", "c-out before", "connected 0"]
    assert r.stderr.splitlines() == ["py-err before", "py-err after"]


def test_every_project_module_imports_pybullet_quietly():
    """The world modules bring pybullet in through the helper: importing them prints nothing."""
    r = subprocess.run([sys.executable, "-c", "import master.world.world, master.world.ground_truth"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "" and r.stderr == ""
