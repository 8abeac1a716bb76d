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
* ``evaluation/`` (like ``benchmarks/`` and ``tests/``) may import everything;
* no import cycle between the project's packages, a subpackage counted as one node
  (``master.world`` is one node, the module ``master.cosim`` another, ``bridges.j2735`` one).

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
}
BUNDLED_RULE = "a bridges module bundled into an FMU (fmus._bundled.<name>) imports only the standard library"
BUNDLED_PACKAGE = "fmus._bundled"  # exists only inside a built FMU (fmus/builder.py)
CYCLE_RULE = "no import cycle between the project's packages (a subpackage is one node)"


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

    violations += _cycles(imports, project)
    return violations, len(imports)


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


def test_the_scan_sees_known_arrows():
    """The scanner finds imports the tree is known to have (module level, inside a function, relative)."""
    seen = set()
    for pkg in project_packages(ROOT):
        for path in (ROOT / pkg).rglob("*.py"):
            seen |= {(i.module, i.target) for i in imports_of(path, ROOT)[0]}
    assert ("master.cosim", "master.scenario") in seen  # module level
    assert ("master.cli", "fmus.builder") in seen  # inside a function
    assert ("fmus.traffic_light.protocol", "fmus._bundled.ab3418") in seen  # the bundled copy
    assert ("fmus.traffic_light.protocol", "bridges.ab3418") in seen  # and its fallback


# -- the checker itself, on planted trees -------------------------------------------------------
def plant(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for pkg in ("bridges", "master", "master/world", "fmus", "fmus/light", "rsu_app", "av_app", "evaluation"):
        init = root / pkg / "__init__.py"
        init.parent.mkdir(parents=True, exist_ok=True)
        if not init.exists():
            init.write_text("")
    return root


CLEAN = {
    "bridges/codec.py": "import json\nfrom bridges import __name__ as _n\n",
    "bridges/wire.py": "import struct\n",
    "master/cosim.py": "from master.world import scene\nimport bridges.codec\nfrom fmus import light\n",
    "master/world/scene.py": "import math\nfrom . import layout\n",
    "master/world/layout.py": "from bridges.codec import json\n",
    "fmus/light/slave.py": ("try:\n    from fmus._bundled import wire\nexcept ImportError:\n"
                           "    from bridges import wire\nfrom ..light import model\n"),
    "fmus/light/model.py": "import math\n",
    "rsu_app/app.py": "import bridges.codec\nfrom . import tracker\n",
    "rsu_app/tracker.py": "import numpy\n",
    "av_app/app.py": "from bridges.wire import struct\n",
    "evaluation/score.py": "import master.cosim\nimport rsu_app.app\nimport av_app.app\nimport fmus.light.model\n",
    "tests/test_x.py": "import master.cosim\nimport rsu_app.app\n",  # tests may import everything
    "benchmarks/b.py": "import rsu_app.app\nimport master.cosim\n",
}


def test_a_clean_tree_passes(tmp_path):
    violations, n = check_tree(plant(tmp_path, CLEAN))
    assert violations == [] and n >= 15, violations


# (file, text, the file:line expected, a piece of the rule expected in the same report)
PLANTED = [
    ("bridges/bad1.py", "import json\nimport master.cosim\n", "bridges/bad1.py:2", "bridges/ imports nothing"),
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
    ("master/bad1.py", "import rsu_app.app\n", "master/bad1.py:1", "master/ never imports"),
    ("master/bad2.py", "def cmd():\n    from av_app.app import main\n", "master/bad2.py:2", "imports av_app.app"),
    ("master/world/bad3.py", "from evaluation.score import x\n", "master/world/bad3.py:1", "master/ never imports"),
    ("fmus/light/bad1.py", "from master import cosim\n", "fmus/light/bad1.py:1", "fmus/ imports only its own"),
    ("fmus/light/bad2.py", "from bridges import codec\n", "fmus/light/bad2.py:1", "imports bridges.codec"),
    ("fmus/light/bad3.py", "from fmus._bundled import wire\nimport bridges.codec\n", "fmus/light/bad3.py:2",
     "imports bridges.codec"),  # bundling wire does not allow codec
    ("fmus/light/bad4.py", "from fmus._bundled import tables\n", "bridges/tables.py:2", BUNDLED_RULE),
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
    """Like master/world/snapshot.py importing master.cosim while master/cosim.py imports master.world:
    master.world and master.cosim are two nodes, the arrow back is relative, inside a function."""
    files = dict(CLEAN)
    files["master/world/snap.py"] = "import math\n\ndef run():\n    from ..cosim import CoSimulation\n"
    violations, _ = check_tree(plant(tmp_path, files))
    assert len(violations) == 1, violations
    v = violations[0]
    assert CYCLE_RULE in v and "master.cosim -> master.world -> master.cosim" in v, v
    assert "master/cosim.py:1" in v and "master/world/snap.py:4" in v, v


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
    files["master/broken.py"] = "def f(:\n"
    violations, _ = check_tree(plant(tmp_path, files))
    assert any(v.startswith("newpkg/__init__.py:1: no rule for the package newpkg/") for v in violations), violations
    assert any(v.startswith("rsu_app/rel.py:1: relative import beyond") for v in violations), violations
    assert any(v.startswith("master/broken.py:1: cannot parse") for v in violations), violations
    assert len(violations) == 3, violations
