"""The commands of the README and of the docs pages work as printed, and their links lead somewhere.

A user copies commands from README.md, or from a page under docs/ it links to,
into a shell at the root of a fresh clone. This test reads every fenced ``sh``
block of README.md and of every ``docs/*.md``, joins backslash continuations,
and takes each command line that starts with ``v2i ``:

* every ``v2i`` invocation on it (also after a pipe) must parse with the CLI's
  own parser (``master.cli.build_parser()``); a refusal names the page and line
  (``docs/sweeps.md:12``);
* the cheap ones run for real, with bash, in a temporary folder laid out like
  the repository root (``scenarios/`` and ``examples/`` linked in, the built FMUs found through
  ``V2I_FMU_DIR``), block by block in page order so that a line can read what
  the line before it wrote (``bsm.json``); each must exit 0. Long ones
  (datasets, training, evaluation on datasets, wall-clock-paced runs) are only
  parsed.

It also checks that no page points at anything outside the repository and that
every relative link of every page leads to a file that exists (and, into a
Markdown page, to a heading that exists). The checks are functions that return
the problems they find, so the self-tests at the end plant a bad command, a
failing command and bad links in a copy and see them named.
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

# `v2i <command>` invocations cheap enough to run in the test suite (a few seconds each)
CHEAP = {"validate", "info", "j2735", "pki", "snapshot", "run", "export-ssp", "examples"}
CONTROL = {"|", "||", "&&", ";", "&"}
REDIRECT = {">", ">>", "<"}
FENCE = re.compile(r"^\s*```(\S*)")
LINK = re.compile(r"\]\(([^)\s]+)\)")


def pages(root: Path = ROOT) -> list[Path]:
    """README.md and every Markdown page under docs/: what a user reads to learn the commands."""
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def page_name(path: Path, root: Path = ROOT) -> str:
    return path.relative_to(root).as_posix()


@dataclass(frozen=True)
class Command:
    page: str  # the page's path from the repository root, e.g. "docs/sweeps.md"
    line: int  # line of the page where the command starts
    text: str  # the command as a shell would read it (continuations joined)
    block: int  # line of its fenced block's opening fence

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"


def sh_blocks(text: str) -> list[tuple[int, list[tuple[int, str]]]]:
    """[(line of the opening fence, [(line number, line), ...])] of every ```sh block."""
    blocks, current, start = [], None, 0
    for n, line in enumerate(text.splitlines(), 1):
        fence = FENCE.match(line)
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


def commands(text: str, page: str) -> list[Command]:
    """Every command line of the page's sh blocks that starts with `v2i `, continuations joined."""
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
                found.append(Command(page, first, joined, start))
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


def all_cheap(command: Command) -> bool:
    return all(is_cheap(a) for a in invocations(command.text))


def all_commands(root: Path = ROOT) -> list[Command]:
    return [c for p in pages(root) for c in commands(p.read_text(), page_name(p, root))]


@lru_cache(maxsize=1)
def parser():
    from master.cli import build_parser

    return build_parser()


def parse_problems(command: Command) -> list[str]:
    """Why the command's v2i invocations do not parse with the CLI, each naming page:line ([] when they do)."""
    argvs = invocations(command.text)
    if not argvs:
        return [f"{command.where}: no v2i invocation found in {command.text!r}"]
    problems = []
    for argv in argvs:
        try:
            args = parser().parse_args(argv)
        except SystemExit as exc:
            problems.append(f"{command.where}: `v2i {shlex.join(argv)}` does not parse with the CLI "
                            f"(exit {exc.code}); the page shows: {command.text}")
            continue
        if not callable(getattr(args, "func", None)):
            problems.append(f"{command.where}: `v2i {argv[0]}` selects no command")
    return problems


def run_problems(block: list[Command], root: Path, workdir: Path, fmu_dir: Path) -> tuple[int, list[str]]:
    """Run the cheap commands of one sh block in order, in `workdir` laid out like the clone's root.

    Returns how many ran and why any failed, each naming page:line.
    """
    v2i = Path(sys.executable).with_name("v2i")
    if not v2i.exists():
        return 0, [f"no `v2i` script beside {sys.executable}: the README's `. .venv/bin/activate` would not "
                   "give the command (is the project installed?)"]
    (workdir / "scenarios").symlink_to(root / "scenarios", target_is_directory=True)
    if (root / "examples").is_dir():  # docs/writing-an-app.md runs the guide's example scenario
        (workdir / "examples").symlink_to(root / "examples", target_is_directory=True)
    env = {**os.environ, "PATH": f"{v2i.parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "V2I_FMU_DIR": str(fmu_dir)}
    ran, problems = 0, []
    for command in block:
        if not all_cheap(command):
            continue
        result = subprocess.run(["bash", "-o", "pipefail", "-c", command.text], cwd=workdir, env=env,
                                capture_output=True, text=True, timeout=600)
        ran += 1
        if result.returncode != 0:
            problems.append(f"{command.where}: `{command.text}` exited {result.returncode}\n"
                            f"stdout: {result.stdout[-2000:]}\nstderr: {result.stderr[-2000:]}")
    return ran, problems


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: markup dropped, lower case, punctuation removed, spaces to dashes."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link keeps its text
    text = text.replace("`", "").replace("*", "").strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def outside_fences(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every line not inside a fenced block (fences themselves left out)."""
    out, inside = [], False
    for n, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            inside = not inside
        elif not inside:
            out.append((n, line))
    return out


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown page's headings (a repeated heading gets -1, -2, … as on GitHub)."""
    seen: dict[str, int] = {}
    found = set()
    for _, line in outside_fences(path.read_text()):
        heading = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not heading:
            continue
        base = slug(heading.group(1))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return found


def link_problems(path: Path, root: Path = ROOT) -> list[str]:
    """What is wrong with a page's pointers, each naming page:line: a pointer into a workplace folder beside
    the clone, a relative link that leaves the repository, leads to no file, or to no heading of its page."""
    name = page_name(path, root)
    problems = []
    for n, line in outside_fences(path.read_text()):
        if "../shared" in line or "/work/" in line:
            problems.append(f"{name}:{n}: points outside the repository: {line.strip()}")
        for target in LINK.findall(line):
            if re.match(r"^[a-z]+://|^mailto:", target):
                continue
            file, _, fragment = target.partition("#")
            dest = (path.parent / file).resolve() if file else path.resolve()
            if not dest.is_relative_to(root.resolve()):
                problems.append(f"{name}:{n}: link {target} leaves the repository")
            elif not dest.exists():
                problems.append(f"{name}:{n}: link {target} points at nothing ({dest.relative_to(root.resolve())} "
                                "does not exist)")
            elif fragment and dest.suffix == ".md" and fragment not in anchors(dest):
                problems.append(f"{name}:{n}: link {target}: {dest.name} has no heading #{fragment}")
    return problems


PAGES = pages()
COMMANDS = all_commands()
BLOCKS = sorted({(c.page, c.block) for c in COMMANDS if all_cheap(c)})


def test_the_pages_show_the_commands_this_test_runs():
    """The extraction itself works: the everyday commands are all found, the README's first scenario among
    them, and the moved reference pages hold commands too (else the tests below would pass on nothing)."""
    assert len(PAGES) > 5 and all(p.exists() for p in PAGES), PAGES
    kinds = {argv[0] for c in COMMANDS for argv in invocations(c.text) if argv}
    assert CHEAP <= kinds, f"no sh block shows a `v2i {sorted(CHEAP - kinds)}` command"
    assert {"dataset", "eval-detector", "train-detector", "eval-tracker", "sweep"} <= kinds
    readme = {argv[0] for c in COMMANDS if c.page == "README.md" for argv in invocations(c.text)}
    assert {"run", "validate"} <= readme, "the README shows no first scenario to validate and run"
    assert {c.page for c in COMMANDS} - {"README.md"}, "no docs page shows a v2i command"


@pytest.mark.parametrize("command", COMMANDS, ids=[c.where for c in COMMANDS])
def test_command_parses(command):
    problems = parse_problems(command)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("page,block", BLOCKS, ids=[f"{p}:{b}" for p, b in BLOCKS])
def test_cheap_commands_run_as_printed(page, block, tmp_path, fmu_dir):
    """The cheap commands of one sh block, in order, in a folder laid out like a fresh clone's root."""
    ran, problems = run_problems([c for c in COMMANDS if (c.page, c.block) == (page, block)],
                                 ROOT, tmp_path, fmu_dir)
    assert not problems, "\n".join(problems)
    assert ran, f"{page}:{block}: no cheap command ran"


@pytest.mark.parametrize("page", PAGES, ids=[page_name(p) for p in PAGES])
def test_links_lead_to_files_that_exist(page):
    """Every relative link leads into the repository, to a file (and heading) that exists; nothing points at a
    workplace folder beside the clone."""
    problems = link_problems(page)
    assert not problems, "\n".join(problems)


# -- the checks can fail: bad commands and links planted in a copy -------------------------------------------

def planted_clone(tmp_path: Path, page: str) -> Path:
    """A folder with a README and one docs page (given as text), laid out like the repository."""
    root = tmp_path / "clone"
    (root / "docs").mkdir(parents=True)
    (root / "README.md").write_text("# Title\n\nSee [the page](docs/x.md).\n\n## A section\n")
    (root / "docs" / "x.md").write_text(page)
    return root


def test_a_command_the_cli_refuses_is_named_by_page_and_line(tmp_path):
    root = planted_clone(tmp_path, "# X\n\n```sh\nv2i validate scenarios/two_vehicles.toml\n"
                                   "v2i run scenarios/two_vehicles.toml \\\n    --no-such-flag 1\n"
                                   "v2i j2735 decode 00 | v2i no-such-command\n```\n\n"
                                   "```toml\nv2i run not-a-command-in-a-toml-block\n```\n")
    found = all_commands(root)
    assert [(c.where, c.block) for c in found] == [("docs/x.md:4", 3), ("docs/x.md:5", 3), ("docs/x.md:7", 3)]
    assert found[1].text.split() == ["v2i", "run", "scenarios/two_vehicles.toml", "--no-such-flag", "1"]
    assert parse_problems(found[0]) == []
    bad = parse_problems(found[1])
    assert len(bad) == 1 and bad[0].startswith("docs/x.md:5: `v2i run scenarios/two_vehicles.toml --no-such-flag 1`")
    piped = parse_problems(found[2])
    assert len(piped) == 1 and piped[0].startswith("docs/x.md:7: `v2i no-such-command`"), piped


def test_a_command_that_fails_is_named_by_page_and_line(tmp_path, fmu_dir):
    root = planted_clone(tmp_path, "# X\n\n```sh\nv2i validate scenarios/two_vehicles.toml\n"
                                   "v2i validate scenarios/no_such_scenario.toml\n"
                                   "v2i dataset --scenario scenarios/ima_world.toml --out data/x --frames 9\n```\n")
    (root / "scenarios").symlink_to(ROOT / "scenarios", target_is_directory=True)
    block = all_commands(root)
    workdir = tmp_path / "work"
    workdir.mkdir()
    ran, problems = run_problems(block, root, workdir, fmu_dir)
    assert ran == 2  # the dataset is only parsed
    assert len(problems) == 1 and problems[0].startswith(
        "docs/x.md:5: `v2i validate scenarios/no_such_scenario.toml` exited 2"), problems


def test_a_link_to_nothing_is_named_by_page_and_line(tmp_path):
    root = planted_clone(tmp_path, "# X\n\n## Two words: here\n\n"
                                   "[ok](../README.md) [ok](../README.md#a-section) [ok](#two-words-here) "
                                   "[ok](https://example.org/nowhere)\n"
                                   "[gone](missing.md)\n"
                                   "[no heading](../README.md#no-such-section) [no heading here](#nowhere)\n"
                                   "[out](../../outside.md) see ../shared/DESIGN.md\n"
                                   "```text\n[in a fence](not-checked.md)\n```\n")
    (tmp_path / "outside.md").write_text("# outside\n")
    assert link_problems(root / "README.md", root) == []
    problems = link_problems(root / "docs" / "x.md", root)
    assert [p.split(": ", 1)[0] for p in problems] == ["docs/x.md:6", "docs/x.md:7", "docs/x.md:7",
                                                        "docs/x.md:8", "docs/x.md:8"], problems
    assert "link missing.md points at nothing" in problems[0]
    assert "README.md has no heading #no-such-section" in problems[1]
    assert "x.md has no heading #nowhere" in problems[2]
    assert "points outside the repository" in problems[3]
    assert "link ../../outside.md leaves the repository" in problems[4]


def test_headings_get_githubs_anchors(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("# 6. The case study's data path\n### metrics.json\n## Events: faults during a run\n"
                    "## `rsu_app` and [links](x.md)\n## Notes\n## Notes\n```toml\n# not a heading\n```\n")
    assert anchors(page) == {"6-the-case-studys-data-path", "metricsjson", "events-faults-during-a-run",
                             "rsu_app-and-links", "notes", "notes-1"}
