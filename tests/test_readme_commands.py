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
    cheap = [c for c in block if all_cheap(c)]
    problems = []
    for batch in batches(cheap, root, fmu_dir):
        procs = [(c, subprocess.Popen(["bash", "-o", "pipefail", "-c", c.text], cwd=workdir, env=env,
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)) for c in batch]
        for command, proc in procs:
            try:
                out, err = proc.communicate(timeout=600)
            except subprocess.TimeoutExpired:
                proc.kill()
                out, err = proc.communicate()
            if proc.returncode != 0:
                problems.append(f"{command.where}: `{command.text}` exited {proc.returncode}\n"
                                f"stdout: {out[-2000:]}\nstderr: {err[-2000:]}")
    return len(cheap), problems


def lone_run(command: Command) -> list[str] | None:
    """The argv of a line that is one `v2i run` and nothing else (no pipe, redirection, second command or
    --out): it writes only a run folder of its own; None for any other line."""
    lexer = shlex.shlex(command.text, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    tokens = list(lexer)
    argvs = invocations(command.text)
    if len(argvs) != 1 or argvs[0][:1] != ["run"] or "--out" in argvs[0]:
        return None
    return None if any(t in CONTROL or t in REDIRECT for t in tokens) else argvs[0]


def fixed_ports(argv: list[str], root: Path, fmu_dir: Path) -> set[str] | None:
    """The endpoints a `v2i run` binds as its scenario fixes them (bus listen addresses, CAN and serial
    ports); None when the scenario does not load (then the line runs alone and says why)."""
    from master.scenario.loader import load_scenario

    args = parser().parse_args(argv)
    old = os.environ.get("V2I_FMU_DIR")
    os.environ["V2I_FMU_DIR"] = str(fmu_dir)
    try:
        resolved = load_scenario(root / args.file, args.set).resolved()
    except Exception:
        return None
    finally:
        if old is None:
            os.environ.pop("V2I_FMU_DIR", None)
        else:
            os.environ["V2I_FMU_DIR"] = old

    def walk(node, key=""):
        if isinstance(node, dict):
            for k, v in node.items():
                yield from walk(v, k)
        elif isinstance(node, list):
            for v in node:
                yield from walk(v, key)
        elif key in ("port", "listen"):
            yield str(node)

    return set(walk(resolved))


def batches(block: list[Command], root: Path, fmu_dir: Path, width: int = 2) -> list[list[Command]]:
    """The block's commands in page order, consecutive lone runs paired (`width` at a time) when their
    scenarios bind no port in common: a lockstep run keeps about one core busy, so two side by side take
    the time of one on this 2-core machine. Any other line runs alone, after what comes before it, since it
    may read what that wrote; runs that share a port run one after the other, as a user would."""
    out: list[list[Command]] = []
    taken: list[set[str]] = []
    for command in block:
        argv = lone_run(command)
        ports = fixed_ports(argv, root, fmu_dir) if argv is not None else None
        if (ports is not None and out and len(out[-1]) < width and taken[-1] is not None
                and not ports & taken[-1]):
            out[-1].append(command)
            taken[-1] |= ports
        else:
            out.append([command])
            taken.append(ports)
    return out


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


def test_lone_runs_on_ports_of_their_own_are_paired_and_everything_else_keeps_its_order(tmp_path, fmu_dir):
    """The shipped case study and its no-CPS variant bind different ports and pair; a run sharing a port with
    the one before it (the same scenario twice) waits for it, as does any line that is not a lone run."""
    cps, no_cps = "scenarios/ima_case_study.toml", "scenarios/ima_no_cps.toml"
    root = planted_clone(tmp_path, f"# X\n\n```sh\nv2i run {cps}\nv2i run {no_cps}   # a comment\n"
                                   f"v2i run {cps}\nv2i run {cps} --set time.stop=2\nv2i run {no_cps} > log\n"
                                   f"v2i run {cps} --out x\nv2i run {no_cps}\nv2i validate {cps}\n"
                                   f"v2i run {cps} && v2i run {no_cps}\nv2i run scenarios/missing.toml\n"
                                   f"v2i run {cps}\n```\n")
    (root / "scenarios").symlink_to(ROOT / "scenarios", target_is_directory=True)
    lines = [[int(c.where.rsplit(":", 1)[1]) - 3 for c in batch] for batch in batches(all_commands(root), root, fmu_dir)]
    assert lines == [[1, 2], [3], [4], [5], [6], [7], [8], [9], [10], [11]], lines


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
