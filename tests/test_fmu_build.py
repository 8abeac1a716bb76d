"""The FMU build pipeline: clean validation, complete model descriptions, content-hash skipping."""
from __future__ import annotations

import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import pytest
from fmpy.validation import validate_fmu

from fmus.builder import BuildError, FmuSource, build_all, discover


def _model_description(fmu: Path) -> ElementTree.Element:
    with zipfile.ZipFile(fmu) as z:
        return ElementTree.fromstring(z.read("modelDescription.xml"))


def test_every_project_fmu_validates_without_messages(fmu_dir):
    fmus = sorted(fmu_dir.glob("*.fmu"))
    assert {f.stem for f in fmus} >= {s.model_identifier for s in discover()}
    for fmu in fmus:
        assert validate_fmu(str(fmu)) == [], fmu.name


def test_vehicle_description_is_complete(vehicle_fmu):
    root = _model_description(vehicle_fmu)
    assert root.find("CoSimulation").get("modelIdentifier") == "VehicleDynamics"
    declared_units = {u.get("name") for u in root.find("UnitDefinitions")}
    variables = root.find("ModelVariables")
    outputs = []
    for index, sv in enumerate(variables, start=1):
        name = sv.get("name")
        assert sv.get("description"), f"{name} has no description"
        assert sv.get("causality") in ("input", "output", "parameter"), name
        assert sv.get("variability"), f"{name} has no variability"
        typed = sv[0]
        if typed.tag == "Real":
            assert typed.get("unit") in declared_units, f"{name}: unit {typed.get('unit')!r} not declared"
        if sv.get("causality") == "output":
            # FMI 2: calculated outputs may not carry a start value
            assert sv.get("initial") == "calculated" and typed.get("start") is None, name
            outputs.append(str(index))
        else:
            assert typed.get("start") is not None, f"{name} has no start value"
    structure = root.find("ModelStructure")
    assert [u.get("index") for u in structure.find("Outputs")] == outputs
    assert [u.get("index") for u in structure.find("InitialUnknowns")] == outputs


def test_vehicle_interface_names(vehicle_fmu):
    """Other issues rely on these names (issue 2)."""
    root = _model_description(vehicle_fmu)
    by_causality: dict[str, set[str]] = {}
    for sv in root.find("ModelVariables"):
        by_causality.setdefault(sv.get("causality"), set()).add(sv.get("name"))
    assert {"accel_cmd", "steer_cmd"} <= by_causality["input"]
    assert {"x0", "y0", "yaw0", "v0", "wheelbase", "mass", "a_max", "a_min", "v_switch",
            "cd_a", "c_rr"} <= by_causality["parameter"]
    assert {"x", "y", "yaw", "v", "a"} <= by_causality["output"]


def test_unchanged_sources_are_skipped(fmu_dir):
    before = (fmu_dir / "VehicleDynamics.fmu").stat().st_mtime_ns
    results = build_all(fmu_dir)
    assert all(not r.built for r in results)
    assert (fmu_dir / "VehicleDynamics.fmu").stat().st_mtime_ns == before


def test_hash_follows_content_not_location(tmp_path, monkeypatch):
    import shutil

    import fmus.builder as builder

    real = next(s for s in discover() if s.model_identifier == "VehicleDynamics")
    copy = tmp_path / "fmus"
    shutil.copytree(builder.PACKAGE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(builder, "PACKAGE_DIR", copy)
    moved = FmuSource(copy / "vehicle", "VehicleDynamics")
    assert moved.content_hash() == real.content_hash()
    model = copy / "vehicle" / "model.py"
    model.write_text(model.read_text() + "\n# changed\n")
    assert moved.content_hash() != real.content_hash()


def test_rebuild_when_output_missing(tmp_path):
    results = build_all(tmp_path)
    assert [r.built for r in results] == [True] * len(results)
    assert all(validate_fmu(str(r.path)) == [] for r in results)
    (tmp_path / "VehicleDynamics.fmu").unlink()
    again = {r.name: r.built for r in build_all(tmp_path)}
    assert again["VehicleDynamics"] is True


def test_fmu_built_from_other_sources_is_rebuilt(tmp_path):
    """The per-user cache is shared by every checkout and install: an FMU whose stamp is another
    source's hash (another version of the project built it) is rebuilt, not taken."""
    (first,) = build_all(tmp_path, only=["TrafficLightController"])
    stamp = tmp_path / "TrafficLightController.sha256"
    ours = stamp.read_text()
    stamp.write_text("0" * 64 + "\n")
    (again,) = build_all(tmp_path, only=["TrafficLightController"])
    assert first.built and again.built and stamp.read_text() == ours
    assert validate_fmu(str(again.path)) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["TrafficLightController.fmu",
                                                          "TrafficLightController.sha256"]  # no leftovers


def test_fmu_folder_does_not_depend_on_the_working_folder(tmp_path, monkeypatch):
    """V2I_FMU_DIR wins; else a checkout keeps its FMUs in its build/fmus, and an installed wheel (no
    pyproject.toml of the project beside its packages) in the user's cache (XDG_CACHE_HOME on Linux);
    from any folder."""
    import fmus.builder as builder
    from conftest import ROOT

    monkeypatch.setenv("V2I_FMU_DIR", str(tmp_path / "mine"))
    assert builder.default_out_dir() == tmp_path / "mine"
    monkeypatch.delenv("V2I_FMU_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    installed = tmp_path / "site-packages" / "fmus"
    installed.mkdir(parents=True)
    (installed.parent / "pyproject.toml").write_text('[project]\nname = "another-project"\n')
    seen = {"checkout": set(), "installed": set()}
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        monkeypatch.chdir(tmp_path / folder)
        seen["checkout"].add(builder.default_out_dir())
        with monkeypatch.context() as m:
            m.setattr(builder, "PACKAGE_DIR", installed)
            seen["installed"].add(builder.default_out_dir())
    assert seen["checkout"] == {ROOT / "build" / "fmus"}
    (cache,) = seen["installed"]
    assert cache.is_absolute() and ROOT not in cache.parents
    if sys.platform.startswith("linux"):
        assert cache == tmp_path / "cache" / "v2i-cosim" / "fmus"


def test_unknown_fmu_name_is_rejected(tmp_path):
    with pytest.raises(BuildError, match="unknown FMU 'NoSuchModel'.*VehicleDynamics"):
        build_all(tmp_path, only=["NoSuchModel"])


def test_many_instances_in_one_process(vehicle_fmu):
    """pythonfmu 0.7.0 over-releases the entry module namespace; the builder's entry
    script compensates. Without it the second instance fails to instantiate."""
    from fmpy import simulate_fmu

    for i in range(25):
        result = simulate_fmu(str(vehicle_fmu), stop_time=0.05, output_interval=0.05,
                              start_values={"v0": float(i)}, output=["v"])
        assert result["v"][0] == pytest.approx(float(i))


def test_fmu_runs_its_own_packaged_code_beside_the_working_tree(vehicle_fmu):
    """Even with the working tree's `fmus` imported in this process, the FMU's slave
    class comes from the copy inside the FMU (a private package name per build)."""
    import sys

    import fmus.vehicle.slave  # noqa: F401  - the working tree's copy is loaded
    from fmpy import simulate_fmu

    simulate_fmu(str(vehicle_fmu), stop_time=0.01)
    entry = sys.modules["VehicleDynamics"]
    module = sys.modules[entry.VehicleDynamics.__module__]
    assert module.__name__.startswith("_v2i_VehicleDynamics_")
    assert "fmus/vehicle" not in Path(module.__file__).as_posix()
    model = sys.modules[module.__name__.replace(".slave", ".model")]
    assert Path(model.__file__).parent == Path(module.__file__).parent
