"""The README's commands work as printed, and the README stands alone.

A user copies commands from README.md into a shell at the root of a fresh
clone. This test reads every fenced ``sh`` block of the README, joins
backslash continuations, and takes each command line that starts with ``v2i ``:

* every ``v2i`` invocation on it (also after a pipe) must parse with the CLI's
  own parser (``master.cli.build_parser()``); a refusal names the README line;
* the cheap ones run for real, with bash, in a temporary folder laid out like
  the repository root (``scenarios/`` linked in, the built FMUs found through
  ``V2I_FMU_DIR``), block by block in README order so that a line can read what
  the line before it wrote (``bsm.json``); each must exit 0. Long ones
  (datasets, training, evaluation on datasets, wall-clock-paced runs) are only
  parsed.

It also checks that the README points at nothing outside the repository.
"""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"

# `v2i <command>` invocations cheap enough to run in the test suite (a few seconds each)
CHEAP = {"validate", "info", "j2735", "pki", "snapshot", "run", "export-ssp"}
CONTROL = {"|", "||", "&&", ";", "&"}
REDIRECT = {">", ">>", "<"}


@dataclass(frozen=True)
class Command:
    line: int  # README line where the command starts
    text: str  # the command as a shell would read it (continuations joined)
    block: int  # README line of its fenced block's opening fence

    @property
    def where(self) -> str:
        return f"README.md:{self.line}"


def sh_blocks(text: str) -> list[tuple[int, list[tuple[int, str]]]]:
    """[(line of the opening fence, [(line number, line), ...])] of every ```sh block."""
    blocks, current, start = [], None, 0
    for n, line in enumerate(text.splitlines(), 1):
        fence = re.match(r"^\s*```(\S*)", line)
        if fence and current is None:
            if fence.group(1) in ("sh", "bash", "shell", "console"):
                current, start = [], n
            else:
                current, start = False, n  # another language: skip to its closing fence
        elif fence and current is not None:
            if current is not False:
                blocks.append((start, current))
            current = None
        elif isinstance(current, list):
            current.append((n, line))
    return blocks


def commands(text: str) -> list[Command]:
    """Every command line of the sh blocks that starts with `v2i `, continuations joined."""
    found = []
    for start, lines in sh_blocks(text):
        pending, first = "", 0
        for n, line in lines:
            if not pending:
                first = n
            stripped = line.rstrip()
            if stripped.endswith("\\"):
                pending += stripped[:-1] + " "
                continue
            joined = (pending + stripped).strip()
            pending = ""
            if joined.startswith("v2i "):
                found.append(Command(first, joined, start))
    return found


def invocations(command: str) -> list[list[str]]:
    """The argv (after `v2i`) of every v2i invocation on a shell line, redirections and comments removed."""
    lexer = shlex.shlex(command, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    segments, current = [], []
    for token in lexer:
        if token in CONTROL:
            segments.append(current)
            current = []
        else:
            current.append(token)
    segments.append(current)
    out = []
    for seg in segments:
        argv, skip = [], False
        for token in seg:
            if skip:
                skip = False
            elif token in REDIRECT:
                skip = True
            else:
                argv.append(token)
        if argv and argv[0] == "v2i":
            out.append(argv[1:])
    return out


def is_cheap(argv: list[str]) -> bool:
    if not argv or argv[0] not in CHEAP:
        return False
    if argv[0] == "run" and "realtime" in argv:  # paced to the wall clock: seconds of real time
        return False
    if argv[0] == "run" and any("ima_rsu_box" in a for a in argv):  # needs the emulated box running beside it
        return False                                                 # (tests/test_rsu_box_case_study.py runs both)
    return True


README_TEXT = README.read_text()
COMMANDS = commands(README_TEXT)


@lru_cache(maxsize=1)
def parser():
    from master.cli import build_parser

    return build_parser()


def test_readme_shows_the_commands_this_test_runs():
    """The extraction itself works: the README's everyday commands are all found (else the tests below
    would pass on nothing)."""
    kinds = {argv[0] for c in COMMANDS for argv in invocations(c.text) if argv}
    assert CHEAP <= kinds, f"README sh blocks show no `v2i {sorted(CHEAP - kinds)}` command"
    assert {"dataset", "eval-detector", "train-detector", "eval-tracker"} <= kinds


@pytest.mark.parametrize("command", COMMANDS, ids=[c.where for c in COMMANDS])
def test_readme_command_parses(command):
    argvs = invocations(command.text)
    assert argvs, f"{command.where}: no v2i invocation found in {command.text!r}"
    for argv in argvs:
        try:
            args = parser().parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"{command.where}: `v2i {shlex.join(argv)}` does not parse with the CLI "
                        f"(exit {exc.code}); the README shows: {command.text}")
        assert callable(getattr(args, "func", None)), f"{command.where}: `v2i {argv[0]}` selects no command"


BLOCKS = sorted({c.block for c in COMMANDS if all(is_cheap(a) for a in invocations(c.text))})


@pytest.mark.parametrize("block", BLOCKS, ids=[f"README.md:{b}" for b in BLOCKS])
def test_readme_cheap_commands_run_as_printed(block, tmp_path, fmu_dir):
    """The cheap commands of one sh block, in order, in a folder laid out like a fresh clone's root."""
    v2i = Path(sys.executable).with_name("v2i")
    assert v2i.exists(), f"no `v2i` script beside {sys.executable}: the README's `. .venv/bin/activate` " \
                         "would not give the command (is the project installed?)"
    (tmp_path / "scenarios").symlink_to(ROOT / "scenarios", target_is_directory=True)
    env = {**os.environ, "PATH": f"{v2i.parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "V2I_FMU_DIR": str(fmu_dir)}
    ran = 0
    for command in (c for c in COMMANDS if c.block == block):
        if not all(is_cheap(a) for a in invocations(command.text)):
            continue
        result = subprocess.run(["bash", "-o", "pipefail", "-c", command.text], cwd=tmp_path, env=env,
                                capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, (f"{command.where}: `{command.text}` exited {result.returncode}\n"
                                        f"stdout: {result.stdout[-2000:]}\nstderr: {result.stderr[-2000:]}")
        ran += 1
    assert ran, f"README.md:{block}: no cheap command ran"


def test_readme_points_at_nothing_outside_the_repository():
    """No pointer into a workplace folder beside the clone; every relative link resolves inside it."""
    for n, line in enumerate(README_TEXT.splitlines(), 1):
        assert "../shared" not in line and "/work/" not in line, f"README.md:{n}: {line.strip()}"
    for n, line in enumerate(README_TEXT.splitlines(), 1):
        for target in re.findall(r"\]\(([^)\s]+)\)", line):
            if re.match(r"^[a-z]+://|^#|^mailto:", target):
                continue
            path = (ROOT / target.split("#", 1)[0]).resolve()
            assert path.is_relative_to(ROOT), f"README.md:{n}: link {target} leaves the repository"
            assert path.exists(), f"README.md:{n}: link {target} points at nothing"
