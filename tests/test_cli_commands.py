"""One `v2i` command composed through the `v2i.commands` entry points (master/cli.py).

Through the installed `v2i` script as a real process: `--help` lists the master's own commands and
every contributed one without importing anything heavy; each command's `--help` works; a command
that needs a missing extra says which in one line (exit 2); an entry point whose module cannot be
imported leaves `--help` working and says why when run. The missing pieces are simulated in the
child process only: a `sitecustomize` on its PYTHONPATH blocks torch/onnx/onnxruntime imports, and
a fake distribution's `entry_points.txt` beside it declares extra (good and broken) commands.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tomllib
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path

import pytest

from master import cli

ROOT = Path(__file__).resolve().parent.parent
V2I = Path(sys.executable).parent / "v2i"  # the console script of the installed project
CORE = ["build-fmus", "validate", "run", "info"]
CONTRIBUTED = ["j2735", "pki", "snapshot", "dataset", "train-detector", "eval-detector", "export-detector",
               "eval-tracker"]  # at least these; pyproject.toml may declare more


def declared_commands() -> list[str]:
    return sorted(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["v2i.commands"])


HEAVY = ["torch", "onnx", "onnxruntime", "pybullet", "matplotlib", "cv2"]
PERCEPTION_HINT = "needs the 'perception' extra: pip install 'v2i-cosim[perception]'"

BLOCK_EXTRAS = """\
import sys


class NotInstalled:
    \"\"\"Imports of the 'perception' extra fail as if it were not installed (nothing left in sys.modules).\"\"\"
    names = ("torch", "onnx", "onnxruntime")

    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in self.names:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


sys.meta_path.insert(0, NotInstalled())
"""
RECORD_MODULES = """\
import atexit
import os
import sys


@atexit.register
def _record():
    with open(os.environ["V2I_TEST_MODULES"], "w") as f:
        f.write("\\n".join(sorted(sys.modules)))
"""
FAKE_PLUGINS = {
    "fake_v2i_plugins-0.1.dist-info/METADATA": "Metadata-Version: 2.1\nName: fake-v2i-plugins\nVersion: 0.1\n",
    "fake_v2i_plugins-0.1.dist-info/entry_points.txt": (
        "[v2i.commands]\n"
        "hello = fake_v2i_hello:add_parser\n"
        "no-module = fake_v2i_not_there:add_parser\n"
        "raises = fake_v2i_raises:add_parser\n"
        "needs-torch = fake_v2i_torch:add_parser\n"),
    "fake_v2i_hello.py": ("def add_parser(sub):\n"
                          "    p = sub.add_parser('hello', help='say hello from a plugin')\n"
                          "    p.add_argument('--name', default='world')\n"
                          "    p.set_defaults(func=lambda a: print(f'hello {a.name}') or 0)\n"),
    "fake_v2i_raises.py": "raise RuntimeError('this plugin is broken')\n",
    "fake_v2i_torch.py": "import torch\n\ndef add_parser(sub):\n    sub.add_parser('needs-torch')\n",
}


def v2i(*args: str, env: dict | None = None, cwd: Path | None = None) -> subprocess.CompletedProcess:
    assert V2I.is_file(), f"no installed v2i script at {V2I}: pip install -e '.[dev]'"
    return subprocess.run([str(V2I), *args], capture_output=True, text=True, timeout=120,
                          env=env, cwd=cwd or ROOT)


@pytest.fixture
def plugin_env(tmp_path):
    """Environment of a child `v2i` with the perception extra blocked and the fake plugins installed."""
    site = tmp_path / "site"
    for rel, text in dict(FAKE_PLUGINS, **{"sitecustomize.py": BLOCK_EXTRAS}).items():
        (site / rel).parent.mkdir(parents=True, exist_ok=True)
        (site / rel).write_text(text)
    env = dict(os.environ, PYTHONPATH=str(site))
    return env


def listed_commands(help_text: str) -> list[str]:
    """Subcommand names of `v2i --help`, from the `{a,b,...}` choices line."""
    line = next(ln for ln in help_text.splitlines() if ln.strip().startswith("{"))
    return line.strip().strip("{}").split(",")


def test_help_lists_every_command():
    r = v2i("--help")
    assert r.returncode == 0, r.stderr
    assert sorted(listed_commands(r.stdout)) == sorted(CORE + declared_commands()), r.stdout
    assert "unavailable" not in r.stdout, r.stdout
    for command in CORE + declared_commands():
        assert f"\n    {command} " in r.stdout, command  # each has its help line


def test_installed_entry_points_are_the_declared_ones():
    """pyproject.toml's [project.entry-points."v2i.commands"] is what the installation offers
    (else: reinstall, pip install -e '.[dev]')."""
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["v2i.commands"]
    installed = {ep.name: ep.value for ep in entry_points(group=cli.COMMANDS_GROUP)}
    assert installed == declared, "installed entry points differ from pyproject.toml: pip install -e '.[dev]'"
    assert set(CONTRIBUTED) <= set(declared) and not set(CORE) & set(declared), sorted(declared)


@pytest.mark.parametrize("ep", sorted(entry_points(group=cli.COMMANDS_GROUP), key=lambda e: e.name),
                         ids=lambda e: e.name)
def test_each_entry_point_adds_the_command_it_is_named_after(ep):
    sub = argparse.ArgumentParser(prog="v2i").add_subparsers(dest="command")
    ep.load()(sub)
    assert ep.name in sub.choices, sorted(sub.choices)


@pytest.mark.parametrize("command", CORE + declared_commands())
def test_each_command_has_its_own_help(command):
    r = v2i(command, "--help")
    assert r.returncode == 0 and r.stdout.startswith(f"usage: v2i {command}"), (r.stdout, r.stderr)
    assert "unavailable" not in r.stdout


def test_help_imports_nothing_heavy(tmp_path):
    """`v2i --help` loads every entry point's module: none may import torch and friends.
    The same record of an `import torch` process holds torch (the check can fail)."""
    (tmp_path / "sitecustomize.py").write_text(RECORD_MODULES)
    out = tmp_path / "modules.txt"
    env = dict(os.environ, PYTHONPATH=str(tmp_path), V2I_TEST_MODULES=str(out))

    def loaded(cmd: list[str]) -> set[str]:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT, env=env)
        assert r.returncode == 0, r.stderr[-2000:]
        return set(out.read_text().split())

    at_help = loaded([str(V2I), "--help"])
    assert {"master.report.snapshot", "rsu_app.perception.cli", "evaluation.cli"} <= at_help  # entry points loaded
    heavy = {m for m in at_help if m.partition(".")[0] in HEAVY}
    assert not heavy, sorted(heavy)
    assert "torch" in loaded([sys.executable, "-c", "import torch"])


def test_a_missing_extra_is_a_one_line_hint(plugin_env, tmp_path):
    assert v2i("--help", env=plugin_env).returncode == 0
    data = tmp_path / "data"
    data.mkdir()
    for args in (["train-detector", "--data", str(data), "--out", str(tmp_path / "w.pt")],
                 ["export-detector", "--weights", str(tmp_path / "w.pt"), "--out", str(tmp_path / "w.onnx")]):
        r = v2i(*args, env=plugin_env)
        assert r.returncode == 2 and r.stdout == "", (r.stdout, r.stderr)
        assert r.stderr == f"v2i {args[0]}: {PERCEPTION_HINT}\n", r.stderr
        assert not (tmp_path / "w.pt").exists() and not (tmp_path / "w.onnx").exists()
    # the detector registry has its own one-line message for a backend whose package is missing
    r = v2i("eval-tracker", "--scenario", "scenarios/ima_world.toml", "--detector", "onnx", env=plugin_env)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1 and "'perception' extra" in r.stderr, r.stderr


def test_plugins_join_and_broken_ones_say_why(plugin_env):
    r = v2i("--help", env=plugin_env)
    assert r.returncode == 0, r.stderr
    commands = listed_commands(r.stdout)
    assert set(CORE + declared_commands() + ["hello", "no-module", "raises", "needs-torch"]) == set(commands), commands
    assert "(unavailable:" in r.stdout and "Traceback" not in r.stderr

    r = v2i("hello", "--name", "rsu", env=plugin_env)  # discovered through its entry point alone
    assert (r.returncode, r.stdout) == (0, "hello rsu\n"), r.stderr

    cases = {
        "no-module": "v2i no-module: needs the Python package 'fake_v2i_not_there', which is not installed\n",
        "raises": "v2i raises: cannot load fake_v2i_raises:add_parser: RuntimeError: this plugin is broken\n",
        "needs-torch": f"v2i needs-torch: {PERCEPTION_HINT}\n",
    }
    for command, said in cases.items():
        r = v2i(command, "--any", "arguments", env=plugin_env)
        assert (r.returncode, r.stdout, r.stderr) == (2, "", said)
    r = v2i("no-module", "--help", env=plugin_env)
    assert r.returncode == 0 and "unavailable: needs the Python package 'fake_v2i_not_there'" in r.stdout


# -- in-process: the pieces of master/cli.py ------------------------------------------------------
def test_an_entry_point_that_does_not_add_its_command(capsys):
    p = argparse.ArgumentParser(prog="v2i")
    sub = p.add_subparsers(dest="command", required=True)
    cli.add_contributed_commands(sub, [EntryPoint("tracker-eval", "evaluation.cli:add_parser", cli.COMMANDS_GROUP)])
    assert {"eval-tracker", "tracker-eval"} <= set(sub.choices)
    args = p.parse_args(["tracker-eval"])
    assert args.func(args) == 2
    assert capsys.readouterr().err == ("v2i tracker-eval: the entry point tracker-eval = evaluation.cli:add_parser "
                                       "did not add the command\n")


def test_missing_module_hint(monkeypatch):
    for name in ("onnxruntime", "pyarrow"):
        monkeypatch.setitem(sys.modules, name, None)  # as if not installed
    assert cli.missing_module_hint(ModuleNotFoundError("x", name="onnxruntime")) == PERCEPTION_HINT
    assert cli.missing_module_hint(ModuleNotFoundError("x", name="pyarrow.parquet")) == (
        "needs the 'parquet' extra: pip install 'v2i-cosim[parquet]'")
    assert cli.missing_module_hint(ModuleNotFoundError("x", name="zz_no_such_pkg")) == (
        "needs the Python package 'zz_no_such_pkg', which is not installed")
    # a module missing from a package that is there is a bug, not an extra to install
    assert cli.missing_module_hint(ModuleNotFoundError("x", name="master.no_such_module")) is None
    assert cli.missing_module_hint(ImportError("x")) is None


def test_a_missing_project_module_is_a_traceback_not_a_hint(monkeypatch, tmp_path):
    (tmp_path / "fake_v2i_buggy.py").write_text(
        "def add_parser(sub):\n"
        "    p = sub.add_parser('buggy')\n"
        "    p.set_defaults(func=lambda a: __import__('master.no_such_module'))\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr("importlib.metadata.entry_points", lambda group: [
        EntryPoint("buggy", "fake_v2i_buggy:add_parser", group)])
    with pytest.raises(ModuleNotFoundError, match="master.no_such_module"):
        cli.main(["buggy"])
    with pytest.raises(SystemExit) as exc:  # unknown arguments of a working command: argparse's error
        cli.main(["buggy", "--nope"])
    assert exc.value.code == 2
