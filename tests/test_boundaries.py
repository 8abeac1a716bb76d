"""The architecture's folder rules, read from the code's own imports (AST, not text).

Rules (DESIGN §1, issue 14):

* ``bridges/`` imports nothing of the project but ``bridges`` (no master, fmus, rsu_app, av_app,
  evaluation): it is what crosses process boundaries, so everyone can import it;
* ``rsu_app/`` and ``av_app/`` import only ``bridges`` of the project (never master, fmus,
  evaluation, never each other): apps are separate processes that talk to the master over the bus;
* ``master/`` never imports rsu_app, av_app or evaluation (it finds the apps' CLI commands
  through the ``v2i.commands`` entry points, not by importing them);
* ``fmus/`` imports only its own package, plus what an FMU bundles on purpose: ``fmus/builder.py``
  stages ``bridges/<name>.py`` into the FMU as ``fmus._bundled.<name>``, so a module of ``fmus/``
  may import ``bridges.<name>`` as the working-tree fallback of that bundled copy, i.e. only when
  the same file also imports ``fmus._bundled.<name>``; such a bundled ``bridges/<name>.py`` imports
  only the standard library (the FMU carries that one file and nothing else of the project);
* ``examples/`` (the guide's minimal app) imports only ``bridges`` of the project, as a new app would;
* ``evaluation/`` (like ``benchmarks/`` and ``tests/``) may import everything;
* no import cycle between the project's packages, a subpackage counted as one node
  (``master.world`` is one node, the module ``master.cli`` another, ``bridges.j2735`` one).

Inside ``master/`` the rooms (issue 37) keep a direction, lowest first: ``fmi`` (one FMU over fmpy),
``scenario`` (reading and checking scenario files), ``world`` (pybullet), ``links`` (apps, serial,
CAN, the V2X air, sensor streams), ``run`` (the stepping loop and the run folder), then ``report`` and
``sweep`` (made of finished runs), and ``cli`` on top. Beside them, flat, the shared modules
(``errors``, ``hooks``, ``events``, ``stats``) that every room may import:

* ``master.fmi`` imports no other room (only the shared modules);
* ``master.scenario`` never imports ``run``, ``links``, ``world``, ``sweep``, ``report`` (it names the
  modules that read the other sections as strings, ``master.scenario.sections``: a registry, read
  only when a scenario has that section);
* ``master.world`` never imports ``run``, ``links``, ``sweep``, ``report``;
* ``master.links`` never imports ``run``, ``sweep``, ``report`` (a link is a hook the loop runs);
* ``master.run`` never imports ``sweep`` or ``report``; ``master.report`` and ``master.sweep``
  never import each other;
* the shared modules import no room;
* nothing inside ``master`` but ``master.cli`` imports ``master.cli``;
* a module flat in ``master/`` is ``cli`` or a shared module, a subpackage is a room: anything else
  is reported, so a new module lands in the room that owns its job (or this list says why not).

What counts as an import: ``import x``, ``from x import y`` (``y`` resolved to the module
``x.y`` when that is a module of the tree), relative imports resolved to absolute names, imports
inside functions and under ``if TYPE_CHECKING`` (an arrow in the design either way), and a literal
``importlib.import_module("x")``. A violation is reported as ``file:line: rule``.

`test_the_checker_reports_each_rule` plants bad imports in a fake tree and asserts each is reported
with its file:line, so a checker that sees nothing cannot pass.
"""
from __future__ import annotations

import ast
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NOT_PACKAGES = {"tests", "benchmarks", "build", "scenarios", "docs"}  # folders that may import everything

# importer's top-level package -> (project packages it may import, the rule in words). None: anything.
RULES: dict[str, tuple[frozenset[str] | None, str]] = {
    "bridges": (frozenset({"bridges"}),
                "bridges/ imports nothing of master, fmus, rsu_app, av_app, evaluation"),
    "rsu_app": (frozenset({"rsu_app", "bridges"}),
                "rsu_app/ and av_app/ import only bridges of the project (never master, fmus, evaluation, "
                "never each other)"),
    "av_app": (frozenset({"av_app", "bridges"}),
               "rsu_app/ and av_app/ import only bridges of the project (never master, fmus, evaluation, "
               "never each other)"),
    "master": (frozenset({"master", "bridges", "fmus"}),
               "master/ never imports rsu_app, av_app or evaluation"),
    "fmus": (frozenset({"fmus"}),
             "fmus/ imports only its own package (and bridges.<name> beside its bundled fmus._bundled.<name>)"),
    "evaluation": (None, "evaluation/ may import everything"),
    "attacker": (frozenset({"attacker", "bridges"}),
                 "attacker/ imports only bridges of the project (a participant like the apps)"),
    "examples": (frozenset({"examples", "bridges"}),
                 "examples/ import only bridges of the project: the guide's app is built the way a new app is "
                 "(docs/writing-an-app.md)"),
    "obu_app": (frozenset({"obu_app", "bridges"}),
                "obu_app/ imports only bridges of the project (a participant like the apps)"),
}
BUNDLED_RULE = "a bridges module bundled into an FMU (fmus._bundled.<name>) imports only the standard library"
BUNDLED_PACKAGE = "fmus._bundled"  # exists only inside a built FMU (fmus/builder.py)
CYCLE_RULE = "no import cycle between the project's packages (a subpackage is one node)"

# The master's rooms (subpackages) and the flat modules beside them; a node is node_of(module).
ROOMS = frozenset({"master.fmi", "master.scenario", "master.world", "master.links", "master.run",
                   "master.report", "master.sweep"})
SHARED = frozenset({"master.errors", "master.hooks", "master.events", "master.stats"})
CLI = "master.cli"
# (importing nodes, nodes they must not import, the rule in words)
ROOM_RULES: list[tuple[frozenset[str], frozenset[str], str]] = [
    (frozenset({"master.fmi"}), ROOMS - {"master.fmi"},
     "master.fmi imports no other room of the master (only errors, hooks, events, stats)"),
    (frozenset({"master.scenario"}),
     frozenset({"master.run", "master.links", "master.world", "master.sweep", "master.report"}),
     "master.scenario never imports master.run, links, world, sweep or report"),
    (frozenset({"master.world"}), frozenset({"master.run", "master.links", "master.sweep", "master.report"}),
     "master.world never imports master.run, links, sweep or report"),
    (frozenset({"master.links"}), frozenset({"master.run", "master.sweep", "master.report"}),
     "master.links never imports master.run, sweep or report"),
    (frozenset({"master.run"}), frozenset({"master.sweep", "master.report"}),
     "master.run never imports master.sweep or master.report"),
    (frozenset({"master.report"}), frozenset({"master.sweep"}), "master.report never imports master.sweep"),
    (frozenset({"master.sweep"}), frozenset({"master.report"}), "master.sweep never imports master.report"),
    (SHARED, ROOMS, "the shared modules of master (errors, hooks, events, stats) import none of its rooms"),
]
CLI_RULE = "nothing inside master but master.cli imports master.cli"
FLAT_RULE = ("master/ holds its rooms (subpackages), cli and the shared modules (errors, hooks, events, "
             "stats): put this module in the room that owns its job, or add it to ROOMS/SHARED in "
             "tests/test_boundaries.py")


@dataclass(frozen=True)
class Import:
    module: str  # importing module, dotted
    path: str  # its file, relative to the root
    line: int
    target: str  # imported module, absolute and dotted (a module of the tree where one matches)


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_module(root: Path, dotted: str) -> bool:
    base = root.joinpath(*dotted.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def project_packages(root: Path) -> list[str]:
    """Top-level folders of the repository holding a Python package."""
    return sorted(p.name for p in root.iterdir()
                  if p.is_dir() and (p / "__init__.py").is_file() and p.name not in NOT_PACKAGES)


def imports_of(path: Path, root: Path) -> tuple[list[Import], list[str]]:
    """Every import of one file (absolute names), and problems reading it ("file:line: why")."""
    rel = path.relative_to(root).as_posix()
    mod = module_name(path, root)
    package = mod.split(".") if path.name == "__init__.py" else mod.split(".")[:-1]
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=rel)
    except SyntaxError as exc:
        return [], [f"{rel}:{exc.lineno}: cannot parse: {exc.msg}"]
    found, problems = [], []

    def add(line: int, target: str) -> None:
        found.append(Import(mod, rel, line, target))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(node.lineno, alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if node.level > len(package):
                    problems.append(f"{rel}:{node.lineno}: relative import beyond the top-level package")
                    continue
                base = package[:len(package) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module
            for alias in node.names:
                sub = f"{source}.{alias.name}"
                is_sub = alias.name != "*" and (source == BUNDLED_PACKAGE or is_module(root, sub))
                add(node.lineno, sub if is_sub else source)
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str) and _is_import_module(node.func)):
            add(node.lineno, node.args[0].value)
    return found, problems


def _is_import_module(func: ast.expr) -> bool:
    return ((isinstance(func, ast.Attribute) and func.attr == "import_module"
             and isinstance(func.value, ast.Name) and func.value.id == "importlib")
            or (isinstance(func, ast.Name) and func.id in ("import_module", "__import__")))


def node_of(dotted: str) -> str:
    """The cycle graph's node of a module: its top-level package and the first name below it."""
    return ".".join(dotted.split(".")[:2])


def check_tree(root: Path) -> tuple[list[str], int]:
    """All violations of the rules in the tree at `root` ("file:line: rule (detail)"), and the number
    of imports read."""
    packages = project_packages(root)
    project = set(packages) | set(RULES)
    violations: list[str] = []
    imports: list[Import] = []
    for pkg in packages:
        if pkg not in RULES:
            violations.append(f"{pkg}/__init__.py:1: no rule for the package {pkg}/: add it to RULES "
                              f"in tests/test_boundaries.py")
        for path in sorted((root / pkg).rglob("*.py")):
            found, problems = imports_of(path, root)
            imports += found
            violations += problems

    by_file: dict[str, list[Import]] = defaultdict(list)
    for imp in imports:
        by_file[imp.path].append(imp)
    bundled: dict[str, Import] = {}  # bridges module name -> first fmus import of fmus._bundled.<name>
    for imp in imports:
        parts = imp.target.split(".")
        if imp.target.startswith(BUNDLED_PACKAGE + ".") and len(parts) > 2:
            bundled.setdefault(parts[2], imp)

    for imp in imports:
        src, dst = imp.module.split(".")[0], imp.target.split(".")[0]
        if dst not in project:
            continue
        allowed, rule = RULES.get(src, (None, ""))
        if allowed is None or dst in allowed:
            continue
        if src == "fmus" and dst == "bridges":
            parts = imp.target.split(".")
            name = parts[1] if len(parts) > 1 else None
            if name and any(o.target == f"fmus._bundled.{name}" for o in by_file[imp.path]):
                continue  # the working-tree fallback of a module the FMU bundles
        violations.append(f"{imp.path}:{imp.line}: {rule} (imports {imp.target})")

    stdlib = set(sys.stdlib_module_names) | {"__future__"}
    for name, via in sorted(bundled.items()):
        rel = f"bridges/{name}.py"
        for imp in by_file.get(rel, []):
            if imp.target.split(".")[0] not in stdlib:
                violations.append(f"{rel}:{imp.line}: {BUNDLED_RULE} (imports {imp.target}; bundled by "
                                  f"{via.path}:{via.line})")

    violations += _rooms(root, imports)
    violations += _cycles(imports, project)
    return violations, len(imports)


def _rooms(root: Path, imports: list[Import]) -> list[str]:
    """The master's room rules: direction between its subpackages, cli on top, nothing flat unnamed."""
    violations = []
    known = ROOMS | SHARED | {CLI, "master"}
    strangers: dict[str, str] = {}  # node -> its first file
    for path in sorted((root / "master").rglob("*.py")) if (root / "master").is_dir() else []:
        node = node_of(module_name(path, root))
        if node not in known:
            strangers.setdefault(node, path.relative_to(root).as_posix())
    violations += [f"{rel}:1: {FLAT_RULE} ({node})" for node, rel in sorted(strangers.items())]
    for imp in imports:
        src, dst = node_of(imp.module), node_of(imp.target)
        if src == dst or src.split(".")[0] != "master" or dst.split(".")[0] != "master":
            continue
        if dst == CLI:
            violations.append(f"{imp.path}:{imp.line}: {CLI_RULE} (imports {imp.target})")
        for importers, forbidden, rule in ROOM_RULES:
            if src in importers and dst in forbidden:
                violations.append(f"{imp.path}:{imp.line}: {rule} (imports {imp.target})")
    return violations


def _cycles(imports: list[Import], project: set[str]) -> list[str]:
    """One report per strongly connected component of the package graph with more than one node."""
    edges: dict[str, dict[str, Import]] = defaultdict(dict)  # a -> b -> first import making the arrow
    for imp in imports:
        a, b = node_of(imp.module), node_of(imp.target)
        if imp.target.split(".")[0] in project and a != b:
            edges[a].setdefault(b, imp)
    reports = []
    for comp in _strongly_connected(edges):
        if len(comp) < 2:
            continue
        cycle = _a_cycle(edges, comp)
        arrows = "; ".join(f"{a} -> {b} at {edges[a][b].path}:{edges[a][b].line}"
                           for a, b in zip(cycle, cycle[1:]))
        first = edges[cycle[0]][cycle[1]]
        others = sorted(set(comp) - set(cycle))
        more = f"; also in the cycle: {', '.join(others)}" if others else ""
        reports.append(f"{first.path}:{first.line}: {CYCLE_RULE}: {' -> '.join(cycle)} ({arrows}{more})")
    return reports


def _strongly_connected(edges: dict[str, dict[str, Import]]) -> list[list[str]]:
    """Tarjan's algorithm (recursive; the package graph has a few dozen nodes)."""
    nodes = sorted(set(edges) | {b for targets in edges.values() for b in targets})
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, {})):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(sorted(comp))

    for v in nodes:
        if v not in index:
            visit(v)
    return out


def _a_cycle(edges: dict[str, dict[str, Import]], comp: list[str]) -> list[str]:
    """A shortest cycle through the component's first node (breadth-first), closed: [a, ..., a]."""
    start, members = comp[0], set(comp)
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(edges.get(v, {})):
                if w not in members:
                    continue
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return path[::-1] + [start]
                if w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"no cycle through {start} in {comp}")  # a component of >= 2 nodes has one


# -- the real tree ------------------------------------------------------------------------------
def test_the_tree_keeps_the_rules():
    violations, n_imports = check_tree(ROOT)
    assert n_imports > 300, f"only {n_imports} imports read: is the scanner looking at the tree?"
    assert not violations, "\n" + "\n".join(violations)


def test_each_room_of_the_master_says_what_it_owns():
    """Every subpackage of master/ is a room of ROOMS whose __init__.py opens with a docstring (what it owns)."""
    found = {f"master.{d.name}" for d in (ROOT / "master").iterdir() if (d / "__init__.py").is_file()}
    assert found == ROOMS, f"rooms on disk {sorted(found)} != ROOMS {sorted(ROOMS)}"
    for room in sorted(ROOMS):
        init = ROOT.joinpath(*room.split("."), "__init__.py")
        doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8"))) or ""
        assert len(doc.split()) >= 20, f"{init.relative_to(ROOT)}: say in a docstring what this room owns"


def test_the_scan_sees_known_arrows():
    """The scanner finds imports the tree is known to have (module level, inside a function, relative)."""
    seen = set()
    for pkg in project_packages(ROOT):
        for path in (ROOT / pkg).rglob("*.py"):
            seen |= {(i.module, i.target) for i in imports_of(path, ROOT)[0]}
    assert ("master.run.cosim", "master.scenario.loader") in seen  # module level
    assert ("master.cli", "fmus.builder") in seen  # inside a function
    assert ("fmus.traffic_light.protocol", "fmus._bundled.ab3418") in seen  # the bundled copy
    assert ("fmus.traffic_light.protocol", "bridges.ab3418") in seen  # and its fallback


# -- the checker itself, on planted trees -------------------------------------------------------
def plant(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for pkg in ("bridges", "master", "master/world", "master/run", "master/scenario", "master/fmi",
                "master/links", "master/report", "master/sweep", "fmus", "fmus/light", "rsu_app", "av_app", "evaluation"):
        init = root / pkg / "__init__.py"
        init.parent.mkdir(parents=True, exist_ok=True)
        if not init.exists():
            init.write_text("")
    return root


CLEAN = {
    "bridges/codec.py": "import json\nfrom bridges import __name__ as _n\n",
    "bridges/wire.py": "import struct\n",
    "master/run/cosim.py": ("from master.world import scene\nimport bridges.codec\nfrom fmus import light\n"
                            "from master.links import can\nfrom master.scenario import loader\n"),
    "master/world/scene.py": "import math\nfrom . import layout\n",
    "master/world/layout.py": "from bridges.codec import json\nfrom master.scenario import tables\n",
    "master/scenario/tables.py": "from master.fmi import variables\nfrom master.errors import E\n",
    "master/scenario/loader.py": "from . import tables\nfrom master.hooks import Hook\n",
    "master/fmi/variables.py": "import math\nfrom master import errors\n",
    "master/errors.py": "class E(Exception):\n    pass\n",
    "master/hooks.py": "from master.events import EventLog\n",
    "master/events.py": "import json\n",
    "master/links/can.py": "from master.scenario.tables import T\nfrom master.hooks import Hook\n",
    "master/run/metrics.py": "from master.stats import p\n",
    "master/stats.py": "import statistics\n",
    "master/report/page.py": "from master.run import metrics\nfrom master.world import scene\n",
    "master/report/cli.py": "from master.report.page import write\n",
    "master/sweep/runner.py": "from master.run.metrics import m\nfrom master.scenario.loader import load\n",
    "master/cli.py": ("from master.run import cosim\nfrom master.report import cli\nfrom master.sweep import runner\n"
                      "from master import __version__\n"),
    "fmus/light/slave.py": ("try:\n    from fmus._bundled import wire\nexcept ImportError:\n"
                           "    from bridges import wire\nfrom ..light import model\n"),
    "fmus/light/model.py": "import math\n",
    "rsu_app/app.py": "import bridges.codec\nfrom . import tracker\n",
    "rsu_app/tracker.py": "import numpy\n",
    "av_app/app.py": "from bridges.wire import struct\n",
    "evaluation/score.py": "import master.run.cosim\nimport rsu_app.app\nimport av_app.app\nimport fmus.light.model\n",
    "tests/test_x.py": "import master.run.cosim\nimport rsu_app.app\n",  # tests may import everything
    "benchmarks/b.py": "import rsu_app.app\nimport master.run.cosim\n",
}


def test_a_clean_tree_passes(tmp_path):
    violations, n = check_tree(plant(tmp_path, CLEAN))
    assert violations == [] and n >= 35, violations


# (file, text, the file:line expected, a piece of the rule expected in the same report)
PLANTED = [
    ("bridges/bad1.py", "import json\nimport master.run.cosim\n", "bridges/bad1.py:2", "bridges/ imports nothing"),
    ("bridges/bad2.py", "from fmus.light import model\n", "bridges/bad2.py:1", "imports fmus.light.model"),
    ("bridges/bad3.py", "def f():\n    import rsu_app.app\n", "bridges/bad3.py:2", "bridges/ imports nothing"),
    ("bridges/bad4.py", "from av_app import app\n", "bridges/bad4.py:1", "imports av_app.app"),
    ("bridges/bad5.py", "import importlib\nimportlib.import_module('evaluation.score')\n", "bridges/bad5.py:2",
     "imports evaluation.score"),
    ("rsu_app/bad1.py", "\n\nfrom master.world import scene\n", "rsu_app/bad1.py:3", "import only bridges"),
    ("rsu_app/bad2.py", "import av_app.app\n", "rsu_app/bad2.py:1", "never each other"),
    ("rsu_app/bad3.py", "def f():\n    from evaluation import score\n", "rsu_app/bad3.py:2", "imports evaluation.score"),
    ("av_app/bad1.py", "import fmus\n", "av_app/bad1.py:1", "import only bridges"),
    ("av_app/bad2.py", "class A:\n    def m(self):\n        from rsu_app import app\n", "av_app/bad2.py:3",
     "imports rsu_app.app"),
    ("master/run/bad1.py", "import rsu_app.app\n", "master/run/bad1.py:1", "master/ never imports"),
    ("master/run/bad2.py", "def cmd():\n    from av_app.app import main\n", "master/run/bad2.py:2",
     "imports av_app.app"),
    ("master/world/bad3.py", "from evaluation.score import x\n", "master/world/bad3.py:1", "master/ never imports"),
    ("fmus/light/bad1.py", "from master import cosim\n", "fmus/light/bad1.py:1", "fmus/ imports only its own"),
    ("fmus/light/bad2.py", "from bridges import codec\n", "fmus/light/bad2.py:1", "imports bridges.codec"),
    ("fmus/light/bad3.py", "from fmus._bundled import wire\nimport bridges.codec\n", "fmus/light/bad3.py:2",
     "imports bridges.codec"),  # bundling wire does not allow codec
    ("fmus/light/bad4.py", "from fmus._bundled import tables\n", "bridges/tables.py:2", BUNDLED_RULE),
    # the master's rooms
    ("master/fmi/bad1.py", "from master.scenario.tables import T\n", "master/fmi/bad1.py:1",
     "master.fmi imports no other room"),
    ("master/fmi/bad2.py", "def f():\n    from master.run import metrics\n", "master/fmi/bad2.py:2",
     "imports master.run.metrics"),
    ("master/scenario/bad1.py", "from master.run.cosim import C\n", "master/scenario/bad1.py:1",
     "master.scenario never imports"),
    ("master/scenario/bad2.py", "from ..links import can\n", "master/scenario/bad2.py:1", "imports master.links.can"),
    ("master/scenario/bad3.py", "import importlib\nimportlib.import_module('master.sweep.runner')\n",
     "master/scenario/bad3.py:2", "master.scenario never imports"),
    ("master/scenario/bad4.py", "from master.report import page\n", "master/scenario/bad4.py:1",
     "master.scenario never imports"),
    ("master/scenario/bad5.py", "from master.world import scene\n", "master/scenario/bad5.py:1",
     "master.scenario never imports"),
    ("master/world/bad4.py", "from master.links.can import X\n", "master/world/bad4.py:1",
     "master.world never imports"),
    ("master/links/bad1.py", "def f():\n    from master.run import metrics\n", "master/links/bad1.py:2",
     "master.links never imports"),
    ("master/run/bad3.py", "from master.sweep import runner\n", "master/run/bad3.py:1",
     "master.run never imports master.sweep or master.report"),
    ("master/run/bad4.py", "def page():\n    from master.report.page import write\n", "master/run/bad4.py:2",
     "master.run never imports master.sweep or master.report"),
    ("master/report/bad1.py", "from master.sweep.runner import r\n", "master/report/bad1.py:1",
     "master.report never imports master.sweep"),
    ("master/sweep/bad1.py", "from master.report import page\n", "master/sweep/bad1.py:1",
     "master.sweep never imports master.report"),
    ("master/bad_shared.py", "import math\n", "master/bad_shared.py:1", FLAT_RULE),
    ("master/rooms/bad.py", "import math\n", "master/rooms/bad.py:1", FLAT_RULE),
    ("master/report/bad2.py", "from master import cli\n", "master/report/bad2.py:1", CLI_RULE),
    ("master/sweep/bad2.py", "def main():\n    from master.cli import entry\n", "master/sweep/bad2.py:2", CLI_RULE),
]


@pytest.mark.parametrize("rel, text, where, rule", PLANTED, ids=[p[0] for p in PLANTED])
def test_the_checker_reports_each_rule(tmp_path, rel, text, where, rule):
    files = dict(CLEAN, **{rel: text})
    if rel == "fmus/light/bad4.py":
        files["bridges/tables.py"] = "import struct\nimport numpy\n"
    violations, _ = check_tree(plant(tmp_path, files))
    hits = [v for v in violations if v.startswith(where + ":") and CYCLE_RULE not in v]
    assert len(hits) == 1 and rule in hits[0], violations
    others = [v for v in violations if v not in hits]  # an upward import may also close a cycle, nothing else
    assert all(CYCLE_RULE in v and where in v for v in others), violations


def test_the_checker_reports_a_cycle_between_subpackages(tmp_path):
    """Like master/world/snap.py importing master.run.cosim while master/run/cosim.py imports master.world:
    master.world and master.run are two nodes, the arrow back is relative, inside a function. The arrow
    back also breaks the world's room rule: both are reported, nothing else."""
    files = dict(CLEAN)
    files["master/world/snap.py"] = "import math\n\ndef run():\n    from ..run.cosim import CoSimulation\n"
    violations, _ = check_tree(plant(tmp_path, files))
    assert len(violations) == 2, violations
    cycles = [v for v in violations if CYCLE_RULE in v]
    assert len(cycles) == 1, violations
    v = cycles[0]
    assert "master.run -> master.world -> master.run" in v, v
    assert "master/run/cosim.py:1" in v and "master/world/snap.py:4" in v, v
    rooms = [v for v in violations if v not in cycles]
    assert rooms[0].startswith("master/world/snap.py:4: master.world never imports"), rooms


def test_the_checker_reports_a_longer_cycle_and_keeps_inner_arrows_out(tmp_path):
    files = dict(CLEAN)
    files["bridges/codec.py"] = "from bridges.transport import bus\nfrom bridges import wire\n"
    files["bridges/transport/__init__.py"] = ""
    files["bridges/transport/bus.py"] = "from . import frames\nfrom bridges.sec.sign import s\n"  # inside: no node
    files["bridges/transport/frames.py"] = "import bridges.transport.bus\n"  # a cycle inside one node: allowed
    files["bridges/sec/__init__.py"] = ""
    files["bridges/sec/sign.py"] = "\n\nfrom bridges.codec import x\n"
    violations, _ = check_tree(plant(tmp_path, files))
    assert len(violations) == 1, violations
    v = violations[0]
    assert "bridges.codec -> bridges.transport -> bridges.sec -> bridges.codec" in v, v
    assert "bridges/codec.py:1" in v and "bridges/transport/bus.py:2" in v and "bridges/sec/sign.py:3" in v, v


def test_the_checker_reports_unknown_packages_and_bad_relative_imports(tmp_path):
    files = dict(CLEAN)
    files["newpkg/__init__.py"] = ""
    files["rsu_app/rel.py"] = "from .. import master\n"
    files["master/run/broken.py"] = "def f(:\n"
    violations, _ = check_tree(plant(tmp_path, files))
    assert any(v.startswith("newpkg/__init__.py:1: no rule for the package newpkg/") for v in violations), violations
    assert any(v.startswith("rsu_app/rel.py:1: relative import beyond") for v in violations), violations
    assert any(v.startswith("master/run/broken.py:1: cannot parse") for v in violations), violations
    assert len(violations) == 3, violations
