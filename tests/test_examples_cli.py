"""`v2i examples DIR`: the shipped scenarios copied out with their layout, never over a user's files.

(The copy from an installed wheel is tests/test_wheel_install.py; here the editable install reads the
checkout's scenarios/.)
"""
from __future__ import annotations

import tomllib

import pytest

from conftest import ROOT
from master.cli import main
from master.scenario.examples_cli import ExamplesError, copy_examples, examples_source


def test_copies_every_shipped_scenario_with_its_layout(tmp_path, capsys):
    assert examples_source() == ROOT / "scenarios"
    assert main(["examples", str(tmp_path / "ex")]) == 0
    shipped = sorted(p.relative_to(ROOT / "scenarios") for p in (ROOT / "scenarios").rglob("*.toml")
                     if "keys" not in p.parts)
    copied = sorted(p.relative_to(tmp_path / "ex") for p in (tmp_path / "ex").rglob("*"))
    assert [p for p in copied if p.suffix] == shipped and len(shipped) >= 10
    assert f"{len(shipped)} files in {tmp_path / 'ex'}" in capsys.readouterr().out
    # what the case study names relative to itself is there
    study = tomllib.loads((tmp_path / "ex" / "ima_case_study.toml").read_text())
    assert (tmp_path / "ex" / study["scenario"]["extends"]).is_file()
    configs = [c[c.index("--config") + 1] for c in (p["command"] for p in study["participants"].values())]
    assert configs and all((tmp_path / "ex" / c).is_file() for c in configs), configs
    assert main(["validate", str(tmp_path / "ex" / "two_vehicles.toml")]) == 0


def test_files_already_there_are_kept_unless_forced(tmp_path, capsys):
    mine = tmp_path / "ex" / "two_vehicles.toml"
    mine.parent.mkdir()
    mine.write_text("# my edits\n")
    assert main(["examples", str(tmp_path / "ex")]) == 2
    err = capsys.readouterr().err
    assert f"{mine} already exists" in err and "--force" in err
    assert mine.read_text() == "# my edits\n" and not (tmp_path / "ex" / "apps").exists()
    assert main(["examples", str(tmp_path / "ex"), "--force"]) == 0
    assert mine.read_bytes() == (ROOT / "scenarios" / "two_vehicles.toml").read_bytes()


def test_keys_a_run_left_are_not_copied(tmp_path):
    source = tmp_path / "shipped"
    (source / "keys").mkdir(parents=True)
    (source / "two_vehicles.toml").write_text("")
    (source / "keys" / "station.toml").write_text("secret = 1\n")
    copied = copy_examples(tmp_path / "ex", source=source)
    assert copied == [tmp_path / "ex" / "two_vehicles.toml"]


def test_an_installation_without_examples_says_where_it_looked(tmp_path, monkeypatch):
    import master

    monkeypatch.setattr(master, "__file__", str(tmp_path / "site" / "master" / "__init__.py"))
    with pytest.raises(ExamplesError, match=r"no example scenarios \(looked in .*site/master/examples"):
        examples_source()
