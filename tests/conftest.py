"""Shared fixtures: the project's built FMUs and a helper to write scenario files."""
from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def fmu_dir() -> Path:
    """The project's FMUs, built (or found up to date) in build/fmus."""
    from fmus.builder import build_all

    out = ROOT / "build" / "fmus"
    build_all(out)
    return out


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
