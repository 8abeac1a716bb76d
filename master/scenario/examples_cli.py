"""`v2i examples DIR`: a copy of the shipped scenarios to run and edit, for a user who installed a wheel.

A clone has them in `scenarios/`; a wheel carries the same `.toml` files as `master/examples/`
(setup.py puts them there). The copy keeps their layout, so what a scenario names relative to itself
(`apps/rsu.toml`, `extends = "ima_world.toml"`, the sweeps' `base = "../ima_case_study.toml"`) is found.
Files already in DIR are never overwritten unless asked (`--force`): they may be the user's edits.
Exit codes as the rest of `v2i`: 0 copied, 2 nothing to copy from or files in the way.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path


class ExamplesError(RuntimeError):
    """The examples cannot be copied; the message says why."""


def examples_source() -> Path:
    """The folder of the shipped scenarios: the installed copy, else the checkout's scenarios/."""
    import master

    package = Path(master.__file__).resolve().parent
    for candidate in (package / "examples", package.parent / "scenarios"):
        if (candidate / "two_vehicles.toml").is_file():
            return candidate
    raise ExamplesError(f"this installation carries no example scenarios (looked in {package / 'examples'} and "
                        f"{package.parent / 'scenarios'}); a wheel built from the project's sources has them")


def example_files(source: Path) -> list[Path]:
    """The example files, relative to `source` (scenario, app and sweep files; never keys a run left)."""
    return sorted(p.relative_to(source) for p in source.rglob("*.toml") if "keys" not in p.relative_to(source).parts)


def copy_examples(dest: Path, force: bool = False, source: Path | None = None) -> list[Path]:
    """Copy the examples into `dest` (made if missing); returns the copied paths."""
    source = source if source is not None else examples_source()
    files = example_files(source)
    in_the_way = [dest / f for f in files if (dest / f).exists()]
    if in_the_way and not force:
        shown = ", ".join(str(p) for p in in_the_way[:3]) + (f" and {len(in_the_way) - 3} more" if len(in_the_way) > 3 else "")
        raise ExamplesError(f"{shown} already exist{'s' if len(in_the_way) == 1 else ''}; "
                            "pass --force to overwrite, or name another folder")
    copied = []
    for relative in files:
        target = dest / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source / relative, target)
        copied.append(target)
    return copied


def add_parser(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser("examples", help="copy the shipped scenarios (case study, app configs, sweeps) into a folder")
    e.add_argument("dir", help="the folder to copy into (made if missing)")
    e.add_argument("--force", action="store_true", help="overwrite files that are already there")
    e.set_defaults(func=_cmd_examples)


def _cmd_examples(args) -> int:
    dest = Path(args.dir)
    try:
        copied = copy_examples(dest, force=args.force)
    except (ExamplesError, OSError) as exc:
        print(f"v2i examples: {exc}", file=sys.stderr)
        return 2
    print(f"{len(copied)} files in {dest}: scenarios, apps/ (the apps' configs), sweeps/")
    print(f"  first run:  v2i run {dest / 'two_vehicles.toml'}")
    return 0
