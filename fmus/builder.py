"""Build the project's FMUs into one folder (`default_out_dir()`), skipping unchanged ones.

Each `fmus/<name>/slave.py` defines one `V2iSlave` subclass; its class name
is the FMU's model identifier. The FMU carries its own copy of the model
sources (the shared base modules and its own folder), so it runs wherever
Python and pythonfmu's runtime are present. A content hash of those sources
(plus pythonfmu's version and this builder) decides whether to rebuild.
Every FMU is checked with `fmpy.validation.validate_fmu`; any message fails
the build.

The folder does not depend on where a command starts: `V2I_FMU_DIR` when set;
else, when these sources are a checkout of the project (an editable install),
the checkout's `build/fmus`, so that each checkout builds from its own sources
and `make clean` removes them; else (an installed wheel) the user's cache
(`~/.cache/v2i-cosim/fmus` on Linux, platformdirs' rule elsewhere). Installs
may share that cache: the hash rebuilds an FMU built from other sources, and a
finished FMU replaces the old file in one rename, so a process loading it never
reads half a file.
"""
from __future__ import annotations

import hashlib
import importlib
import inspect
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
FMU_DIR_VARIABLE = "V2I_FMU_DIR"  # overrides the default folder below
DISTRIBUTION = "v2i-cosim"


def checkout_root() -> Path | None:
    """The project checkout these sources belong to (its pyproject.toml names the project), or None
    when they were installed from a wheel."""
    root = PACKAGE_DIR.parent
    try:
        declares = f'name = "{DISTRIBUTION}"' in (root / "pyproject.toml").read_text()
    except OSError:
        return None
    return root if declares else None


def default_out_dir() -> Path:
    """Where project FMUs are built and found: `$V2I_FMU_DIR`, else a checkout's build/fmus, else the
    per-user cache folder (see the module's docstring)."""
    override = os.environ.get(FMU_DIR_VARIABLE)
    if override:
        return Path(override).expanduser()
    root = checkout_root()
    if root is not None:
        return root / "build" / "fmus"
    import platformdirs

    return platformdirs.user_cache_path(DISTRIBUTION, appauthor=False) / "fmus"

# Modules of the `fmus` package every FMU needs at run time.
_SHARED_MODULES = ("__init__.py", "slave_base.py", "units.py")
# Wire-format modules shared with the apps: an FMU source that imports
# `fmus._bundled.<name>` gets a private copy of `bridges/<name>.py` as that module
# (stdlib-only modules; the FMU cannot import the host's `bridges`).
BRIDGES_DIR = Path(__file__).resolve().parent.parent / "bridges"
_BUNDLED_IMPORT = re.compile(r"\bfmus\._bundled(?:\.(\w+)|\s+import\s+(\w+))")


# pythonfmu 0.7.0's runtime finds the slave class by re-executing this file in
# the module's namespace and then releases a reference to that namespace it
# never took (a Py_DECREF on the borrowed module dict). Without a balancing
# reference per execution the namespace is freed after the first instance and
# the next instantiation in the same process fails or crashes.
_ENTRY_TEMPLATE = '''"""Entry point of the {cls} FMU (pythonfmu loads it by file name)."""
import ctypes as _ctypes

_ctypes.pythonapi.Py_IncRef(_ctypes.py_object(globals()))  # see fmus/builder.py

from {module} import {cls}  # noqa: E402,F401
'''


class BuildError(RuntimeError):
    """An FMU could not be built or did not validate."""


@dataclass(frozen=True)
class FmuSource:
    """One FMU of the project: its folder and its slave class name."""

    folder: Path
    model_identifier: str

    def staged_files(self) -> list[tuple[Path, Path]]:
        """(source, path inside the FMU's private package) of every file the FMU carries."""
        own = sorted(p for p in self.folder.rglob("*.py") if "__pycache__" not in p.parts)
        files = [(PACKAGE_DIR / m, Path(m)) for m in _SHARED_MODULES]
        files += [(p, p.relative_to(self.folder.parent)) for p in own]
        names = sorted({a or b for p in own for a, b in _BUNDLED_IMPORT.findall(p.read_text())})
        for name in names:
            path = BRIDGES_DIR / f"{name}.py"
            if not path.is_file():
                raise BuildError(f"{self.folder}: imports fmus._bundled.{name}, but {path} does not exist")
            files.append((path, Path("_bundled") / path.name))
        return files

    def source_files(self) -> list[Path]:
        return [path for path, _ in self.staged_files()]

    def content_hash(self) -> str:
        import pythonfmu

        digest = hashlib.sha256()
        digest.update(f"pythonfmu {pythonfmu.__version__}\n".encode())
        digest.update(b"builder.py\0" + Path(__file__).resolve().read_bytes() + b"\0")
        for path, label in self.staged_files():
            digest.update(str(label).encode() + b"\0" + path.read_bytes() + b"\0")
        return digest.hexdigest()


@dataclass(frozen=True)
class BuildResult:
    name: str
    path: Path
    built: bool  # False when skipped because nothing changed


def discover() -> list[FmuSource]:
    """All FMUs of the project: every `fmus/<name>/slave.py` with one V2iSlave class."""
    from fmus.slave_base import V2iSlave

    sources = []
    for slave_file in sorted(PACKAGE_DIR.glob("*/slave.py")):
        module = importlib.import_module(f"fmus.{slave_file.parent.name}.slave")
        classes = [
            obj for _, obj in inspect.getmembers(module, inspect.isclass)
            if issubclass(obj, V2iSlave) and obj is not V2iSlave and obj.__module__ == module.__name__
        ]
        if len(classes) != 1:
            raise BuildError(f"{slave_file}: expected exactly one V2iSlave subclass, found {len(classes)}")
        sources.append(FmuSource(slave_file.parent, classes[0].__name__))
    return sources


_FMUS_IMPORT = re.compile(r"^(\s*)(from|import)\s+fmus(?=[.\s])", re.MULTILINE)


def package_alias(source: FmuSource, digest: str) -> str:
    """Name of the FMU's private copy of the `fmus` package.

    The FMU runs inside the importing Python process. Under the plain name
    `fmus` it would pick up whatever `fmus` that process already imported
    (the working tree, or another FMU's copy) instead of its own sources.
    """
    return f"_v2i_{source.model_identifier}_{digest[:12]}"


def _stage(source: FmuSource, staging: Path, alias: str) -> Path:
    """Lay out the FMU's resources: an entry script and a private copy of its sources."""
    package = staging / alias  # beside the entry script: the build imports it from there
    for path, relative in source.staged_files():
        target = package / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(_FMUS_IMPORT.sub(rf"\1\2 {alias}", path.read_text()))
        if relative.parts[0] == "_bundled":
            (target.parent / "__init__.py").touch()
    # pythonfmu imports the entry script by its file name inside the FMU;
    # naming it after the model identifier keeps FMUs apart in one process.
    entry = staging / f"{source.model_identifier}.py"
    module = f"{alias}.{source.folder.name}.slave"
    entry.write_text(_ENTRY_TEMPLATE.format(module=module, cls=source.model_identifier))
    return entry


def build_one(source: FmuSource, out_dir: Path) -> Path:
    """Build and validate one FMU; returns the `.fmu` path."""
    from fmpy.validation import validate_fmu
    from pythonfmu.builder import FmuBuilder

    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{source.model_identifier}.fmu"
    alias = package_alias(source, source.content_hash())
    with tempfile.TemporaryDirectory(prefix="v2i-fmu-") as tmp, \
            tempfile.TemporaryDirectory(prefix=f".{source.model_identifier}-", dir=out_dir) as fresh:
        entry = _stage(source, Path(tmp), alias)
        # Built beside the target, then renamed over it: another process may be loading the old one.
        built = Path(fresh) / target.name
        FmuBuilder.build_FMU(entry, dest=built, project_files=[Path(tmp) / alias])
        problems = validate_fmu(str(built))
        if problems:
            raise BuildError(f"{source.model_identifier}.fmu does not validate: " + "; ".join(problems))
        os.replace(built, target)
    return target


def build_all(out_dir: Path | None = None, force: bool = False, only: list[str] | None = None) -> list[BuildResult]:
    """Build every FMU whose sources changed since its last build (or all with `force`) into `out_dir`
    (default: `default_out_dir()`)."""
    out_dir = Path(out_dir) if out_dir is not None else default_out_dir()
    results = []
    sources = discover()
    known = {s.model_identifier for s in sources}
    for name in only or []:
        if name not in known:
            raise BuildError(f"unknown FMU {name!r}; the project has: {', '.join(sorted(known))}")
    for source in sources:
        if only and source.model_identifier not in only:
            continue
        fmu = out_dir / f"{source.model_identifier}.fmu"
        stamp = out_dir / f"{source.model_identifier}.sha256"
        digest = source.content_hash()
        if not force and fmu.exists() and stamp.exists() and stamp.read_text().strip() == digest:
            results.append(BuildResult(source.model_identifier, fmu, built=False))
            continue
        build_one(source, out_dir)
        stamp.write_text(digest + "\n")
        results.append(BuildResult(source.model_identifier, fmu, built=True))
    return results


def project_fmu_path(name: str, out_dir: Path | None = None) -> Path | None:
    """Path of a project FMU by model identifier, building it if needed; None if unknown."""
    if name not in {s.model_identifier for s in discover()}:
        return None
    (result,) = build_all(out_dir, only=[name])
    return result.path
