"""Shared fixtures: the project's built FMUs and a helper to write scenario files."""
from __future__ import annotations

import os
import shutil
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "tests" / "fixtures"
# The suite's FMUs are this checkout's build/fmus (where a checkout builds them, fmus.builder.default_out_dir,
# and what `make clean` removes), also when the user's V2I_FMU_DIR names another folder: every `v2i`
# process a test starts, and the master in this process, look there.
FMU_DIR = ROOT / "build" / "fmus"
os.environ["V2I_FMU_DIR"] = str(FMU_DIR)


def fixture_path(relative: str) -> Path:
    """A data file the tests carry in tests/fixtures/ (tests/fixtures/README.md says where each comes from).

    A missing file is an error naming the path, never a skip: a test that cannot
    see its data has not passed.
    """
    path = FIXTURES / relative
    if not path.is_file():
        raise FileNotFoundError(f"test data {path} is missing (tests/fixtures/README.md lists every file the "
                                "tests carry and where it comes from)")
    return path


def has_cxx_compiler() -> bool:
    """Whether torch.compile can build CPU code here (it needs a C++ compiler on PATH)."""
    return shutil.which("c++") is not None or shutil.which("g++") is not None


@pytest.fixture(scope="session")
def fmu_dir() -> Path:
    """The project's FMUs, built (or found up to date) in build/fmus."""
    from fmus.builder import build_all

    build_all(FMU_DIR)
    return FMU_DIR


@pytest.fixture(scope="session")
def vehicle_fmu(fmu_dir) -> Path:
    return fmu_dir / "VehicleDynamics.fmu"


@pytest.fixture
def write_scenario(tmp_path, vehicle_fmu):
    """write_scenario(text) -> path of a scenario file; `{vehicle}` expands to the FMU path."""
    counter = iter(range(1000))

    def write(text: str, name: str | None = None) -> Path:
        path = tmp_path / (name or f"scenario{next(counter)}.toml")
        path.write_text(textwrap.dedent(text).replace("{vehicle}", str(vehicle_fmu)))
        return path

    return write


_EXIT_STATUS: list[int] = []


def pytest_sessionfinish(session, exitstatus):
    _EXIT_STATUS.append(int(exitstatus))


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """Leave with pytest's status without native libraries' exit-time teardown.

    After every test had passed, the process was seen to abort (glibc: corrupted
    heap) inside library destructors run by exit(): Mesa's EGL, libgfortran of
    OpenCV's wheel, with pybullet, zenoh and pythonfmu FMUs loaded in the same
    process. The status pytest computed is the result; the README notes this.
    """
    import os
    import sys

    if _EXIT_STATUS and os.environ.get("V2I_NATIVE_EXIT") != "1":
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_EXIT_STATUS[-1])
