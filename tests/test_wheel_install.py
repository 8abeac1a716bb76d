"""The project as a user gets it from a wheel, far from this checkout.

`pip wheel .` once shipped only the `.py` files: installed from that wheel,
`v2i j2735 decode` ended in FileNotFoundError for the ASN.1 module beside the
codec, and `v2i run` built FMUs into `./build/fmus` of whatever folder the user
stood in. This test builds the wheel from a copy of the checkout's files,
installs it into a fresh virtualenv whose only other entry is this
environment's site-packages (for the dependencies; its `.pth` files, among them
the editable install's path to this checkout, are not read), and then, in a
temporary folder, does what a new user does: decode a signed BSM, build the
FMUs, fetch the example scenarios and run one. The checkout must not be
importable there, FMUs must land in the per-user cache and no `build/` may
appear in the user's folder.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from conftest import ROOT, fixture_path

DOC = ROOT / "docs" / "installing.md"
PACKAGES = ("master", "bridges", "fmus", "rsu_app", "av_app", "evaluation", "attacker")
SIGNED_BSM = next(v for v in json.loads(fixture_path("interop/j2735_vectors.json").read_text())
                  if v["message"] == "IEEE1609.2(signed)+BSM")


def _run(args, cwd, env, timeout=300) -> subprocess.CompletedProcess:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{args} exited {done.returncode}\nstdout:\n{done.stdout}\nstderr:\n{done.stderr}"
    return done


def _checkout_copy(dest: Path) -> Path:
    """The checkout's files as a clone would have them (tracked and new, not ignored): building in the
    checkout itself would leave setuptools' build/ there and pick up stale files from an earlier build."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():  # a tracked file deleted in the working tree is not part of the build
            target = dest / name
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(source.read_bytes())
    return dest


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("wheel")
    source = _checkout_copy(tmp / "src")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
          "-w", str(tmp / "dist"), str(source)], cwd=tmp, env=os.environ.copy())
    (built,) = (tmp / "dist").glob("v2i_cosim-*.whl")
    return built


@pytest.fixture(scope="module")
def user(tmp_path_factory, wheel):
    """(python, v2i, env, folder): a fresh virtualenv with the wheel installed, and an empty working folder."""
    tmp = tmp_path_factory.mktemp("user")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp, env=os.environ.copy())
    python = venv / "bin" / "python"
    site = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp, env=os.environ.copy()).stdout.strip())
    # The dependencies come from this environment: a path line, which adds the folder without reading
    # the .pth files in it (so not the editable install's line that points at the checkout).
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "v2i_test_dependencies.pth").write_text("".join(f"{p}\n" for p in sorted(ours)))
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "-q",
          str(wheel)], cwd=tmp, env=os.environ.copy())
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "V2I_", "VIRTUAL_ENV"))}
    env["HOME"] = str(tmp / "home")  # this pretend user's home and cache, not the tester's
    env["XDG_CACHE_HOME"] = str(tmp / "home" / ".cache")
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    folder = tmp / "work"
    folder.mkdir()
    return python, venv / "bin" / "v2i", env, folder


def test_the_wheel_carries_every_data_file_of_the_packages(wheel):
    """Every file the packages hold besides Python sources (ASN.1 modules, the DBC, the detector's
    weights) is in the wheel: the code opens them beside itself."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "--cached", "--others", "--exclude-standard",
                             *PACKAGES], capture_output=True, text=True, check=True).stdout.split()
    data = {n for n in listed if not n.endswith(".py") and (ROOT / n).is_file()}
    assert {"bridges/j2735/v2i-j2735.asn", "bridges/security/v2i-1609dot2.asn", "bridges/can/cav.dbc",
            "rsu_app/perception/weights/detector.onnx"} <= data
    names = set(zipfile.ZipFile(wheel).namelist())
    assert sorted(data - names) == []
    assert set(re.findall(r"v2i_cosim-[^\s\[\]\"`]*\.whl", DOC.read_text())) == {wheel.name}  # the page's file name
    examples = {n for n in names if n.startswith("master/examples/")}
    assert {"master/examples/two_vehicles.toml", "master/examples/ima_case_study.toml",
            "master/examples/apps/av.toml", "master/examples/apps/rsu.toml"} <= examples
    assert all(n.endswith(".toml") for n in examples), sorted(examples)  # never keys made by a run


def doc_commands(path: Path = DOC) -> list[str]:
    """The `v2i ...` lines of the page's ```sh blocks, in order (the install lines need the network)."""
    found, inside = [], False
    for line in path.read_text().splitlines():
        if line.startswith("```"):
            inside = not inside and line.strip() in ("```sh", "```bash")
        elif inside and line.startswith("v2i "):
            found.append(line.split("  #")[0].strip())
    return found


def test_installed_user_decodes_builds_and_runs_outside_the_checkout(user):
    """docs/installing.md's commands, as printed, by a user of the installed wheel in an empty folder."""
    python, v2i, env, folder = user
    paths = json.loads(_run([str(python), "-c", "import json, sys; print(json.dumps(sys.path))"],
                            cwd=folder, env=env).stdout)
    assert not [p for p in paths if p and Path(p).resolve() == ROOT], paths
    where = _run([str(python), "-c", "import bridges, master; print(bridges.__file__); print(master.__file__)"],
                 cwd=folder, env=env).stdout.split()
    assert all(ROOT not in Path(p).resolve().parents for p in where), where

    commands = doc_commands()
    assert [c.split()[1] for c in commands] == ["j2735", "build-fmus", "examples", "run"], commands
    outputs = [_run(["bash", "-c", command], cwd=folder, env=env).stdout for command in commands]
    assert json.loads(outputs[0])["messageId"] == 20  # the page's BSM, through the installed ASN.1 module

    cache = Path(env["XDG_CACHE_HOME"]) / "v2i-cosim" / "fmus"
    assert sorted(p.name for p in cache.glob("*.fmu")) == [
        "SignalDriver.fmu", "TrafficLightController.fmu", "V2XChannel.fmu", "VehicleDynamics.fmu"]
    assert str(cache / "VehicleDynamics.fmu") in outputs[1]
    assert (folder / "v2i-examples" / "apps" / "av.toml").is_file()
    (run,) = (folder / "runs").iterdir()
    rows = (run / "timeseries.csv").read_text().splitlines()
    assert rows[0].split(",")[:2] == ["time", "cav.x"] and len(rows) > 50, rows[:3]
    assert not (folder / "build").exists(), sorted(p.name for p in folder.iterdir())
    assert not (folder / "v2i-examples" / "build").exists()

    # The 1609.2 module ships too: a signed BSM is unwrapped.
    decoded = json.loads(_run([str(v2i), "j2735", "decode", SIGNED_BSM["hex"]], cwd=folder, env=env).stdout)
    assert decoded["messageId"] == 20 and decoded["ieee1609dot2"]["psid"] == 32
