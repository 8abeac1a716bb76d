"""The `v2i` command line.

The master's own commands (build-fmus, validate, run, info) are defined here;
every other command is contributed through the `v2i.commands` entry points
(pyproject.toml), the way pytest and flask find their plugins: each entry
point's name is a command and its value a function `add_parser(subparsers)`
that adds it (a function adding several commands is named once per command
and called once). So the master imports no app: the RSU app's detector tools
and the evaluation tools join the one `v2i` command from their own packages.

Loading the entry points stays cheap (their modules import nothing heavy at
module level), and a contributed command that cannot run here says why in one
line instead of a traceback: a missing optional extra (torch, onnxruntime)
names the extra to install; an entry point whose module cannot be imported
still leaves `v2i --help` working and answers with the reason when run.

Exit codes: 0 success, 1 the run failed (FMU error, deadline miss,
interrupted), 2 bad input (scenario, FMU file, arguments) or a command that
cannot run in this installation (missing extra, broken entry point).
"""
from __future__ import annotations

import argparse
import importlib.util
import re
import sys
from dataclasses import replace
from pathlib import Path

COMMANDS_GROUP = "v2i.commands"  # entry-point group of the contributed commands
DISTRIBUTION = "v2i-cosim"  # whose optional extras the missing-module hint names



def _cmd_build_fmus(args) -> int:
    from fmus.builder import BuildError, build_all

    try:
        results = build_all(Path(args.out) if args.out else None, force=args.force, only=args.names or None)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for r in results:
        print(f"{'built  ' if r.built else 'up to date'} {r.name:24s} {r.path}")
    return 0


def _cmd_validate(args) -> int:
    from master.scenario.loader import load_scenario_or_report

    worst = 0
    for path in args.files:
        sc = load_scenario_or_report(path, args.set)
        if sc is None:
            worst = 2
            continue
        print(f"{path}: ok ({len(sc.instances)} instances, {len(sc.connections)} connections, "
              f"{sc.time.n_steps} steps of {sc.time.step} s, {sc.time.mode}, {sc.time.ordering})")
    return worst


def _cmd_run(args) -> int:
    from master.run.cosim import CoSimulation
    from master.scenario.loader import load_scenario_or_report
    from master.run.summary import format_summary

    sc = load_scenario_or_report(args.file, args.set)
    if sc is None:
        return 2
    overrides = {k: v for k, v in (("mode", args.mode), ("ordering", args.ordering),
                                   ("rtf", args.rtf), ("overrun", args.overrun)) if v is not None}
    if args.rtf is not None and args.rtf <= 0:
        print(f"error: --rtf must be > 0, got {args.rtf}", file=sys.stderr)
        return 2
    sc.time = replace(sc.time, **overrides)
    try:
        result = CoSimulation(sc, Path(args.out) if args.out else None, quiet=args.quiet).run()
    except FileExistsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(format_summary(result))
    if result.status not in ("completed", "stopped"):
        print(f"error: {result.error}", file=sys.stderr)
        return 1
    if result.metadata.get("metrics") and not args.no_report:
        _write_run_report(result.run_dir)
    return 0


def _write_run_report(run_dir: Path) -> None:
    """The run page beside the data; a run that finished is never failed by its report."""
    try:
        from master.report.page import write_report

        page, _ = write_report([run_dir])
    except Exception as exc:  # noqa: BLE001 -- matplotlib/PyAV trouble leaves the recorded run as it is
        print(f"  report: not written ({type(exc).__name__}: {exc}); retry with `v2i report {run_dir}`",
              file=sys.stderr)
        return
    print(f"  report: {page}")


def _cmd_info(args) -> int:
    from master.fmi.info import describe
    from master.scenario.loader import resolve_fmu

    try:
        print(describe(resolve_fmu(args.fmu, Path.cwd())))
    except (FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    from master import __version__

    p = argparse.ArgumentParser(prog="v2i", description="V2I co-simulation: FMUs, scenarios, runs.")
    p.add_argument("--version", action="version", version=f"v2i-cosim {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    b = sub.add_parser("build-fmus", help="build the project's FMUs (skips unchanged ones)")
    b.add_argument("names", nargs="*", help="model identifiers to build (default: all)")
    b.add_argument("--out", help="output folder (default: where `v2i run` looks: $V2I_FMU_DIR, else a checkout's "
                   "build/fmus, else the per-user cache, e.g. ~/.cache/v2i-cosim/fmus)")
    b.add_argument("--force", action="store_true", help="rebuild even if sources are unchanged")
    b.set_defaults(func=_cmd_build_fmus)

    v = sub.add_parser("validate", help="check scenario files without running them")
    v.add_argument("files", nargs="+")
    add_set_argument(v)
    v.set_defaults(func=_cmd_validate)

    r = sub.add_parser("run", help="run a scenario into a run folder")
    r.add_argument("file")
    add_set_argument(r)
    r.add_argument("--out", help="run folder (default: runs/<scenario>-<timestamp>); never overwritten")
    r.add_argument("--mode", choices=("lockstep", "realtime"), help="override time.mode")
    r.add_argument("--ordering", choices=("jacobi", "gauss-seidel"), help="override time.ordering")
    r.add_argument("--rtf", type=float, help="realtime: target real-time factor (override time.rtf)")
    r.add_argument("--overrun", choices=("catch-up", "skip", "slip", "abort"), help="realtime overrun policy")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--no-report", action="store_true",
                   help="skip report.html (written when the run has metrics: the case study's verdict)")
    r.set_defaults(func=_cmd_run)

    i = sub.add_parser("info", help="list an FMU's variables")
    i.add_argument("fmu", help="an .fmu file or a project FMU name")
    i.set_defaults(func=_cmd_info)

    add_contributed_commands(sub)
    return p


def add_set_argument(p: argparse.ArgumentParser) -> None:
    """`--set KEY=VALUE` (repeatable): a scenario value overridden (master.scenario.overrides has the rules)."""
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a value of the scenario, e.g. --set fmus.ev.parameters.v0=20.1 "
                        "--set v2x.channel.technology=cv2x --set 'world.cameras[rsu_cam].z=10.0' (repeatable). "
                        "VALUE is a TOML literal (20.1, true, \"a b\", [1, 2], { k = 1 }); a bare word that is "
                        "none (cv2x, tcp/127.0.0.1:7447) is that string. Checked like the file itself")


def add_contributed_commands(sub: argparse._SubParsersAction, entry_points=None) -> None:
    """Add the commands of the `v2i.commands` entry points to `sub` (`entry_points`: an iterable of
    importlib.metadata.EntryPoint, default the installed ones). An entry point that cannot be loaded,
    or whose function did not add its command, becomes a command that says why when run."""
    if entry_points is None:
        from importlib.metadata import entry_points as installed

        entry_points = installed(group=COMMANDS_GROUP)
    by_target: dict[str, list] = {}
    for ep in entry_points:
        by_target.setdefault(ep.value, []).append(ep)
    for target, eps in sorted(by_target.items(), key=lambda item: min(ep.name for ep in item[1])):
        names = sorted({ep.name for ep in eps})
        try:
            add_parser = eps[0].load()
        except Exception as exc:  # noqa: BLE001 - any failure to import a plugin must leave `v2i` usable
            reason = missing_module_hint(exc) or f"cannot load {target}: {type(exc).__name__}: {exc}"
            for name in names:
                _add_unavailable(sub, name, reason)
            continue
        add_parser(sub)
        for name in names:
            if name not in sub.choices:
                _add_unavailable(sub, name, f"the entry point {name} = {target} did not add the command")


def _add_unavailable(sub: argparse._SubParsersAction, name: str, reason: str) -> None:
    """A command that only says why it cannot run (exit 2), whatever its arguments."""
    p = sub.add_parser(name, help=f"(unavailable: {reason})", description=f"unavailable: {reason}")
    p.set_defaults(func=lambda args: _cannot_run(name, reason), accepts_any_arguments=True)


def _cannot_run(command: str, reason: str) -> int:
    print(f"v2i {command}: {reason}", file=sys.stderr)
    return 2


def missing_module_hint(exc: BaseException) -> str | None:
    """One line saying which optional extra (or package) a ModuleNotFoundError asks for, or None when
    the missing module is not a missing installation (a module of an installed package, a bug)."""
    if not isinstance(exc, ModuleNotFoundError) or not exc.name:
        return None
    top = exc.name.split(".")[0]
    try:
        if importlib.util.find_spec(top) is not None:
            return None  # the package is there: a missing submodule is not an extra to install
    except (ImportError, ValueError):
        pass
    extra = _extra_providing(top)
    if extra:
        return f"needs the '{extra}' extra: pip install '{DISTRIBUTION}[{extra}]'"
    return f"needs the Python package '{top}', which is not installed"


def _extra_providing(module: str) -> str | None:
    """The optional extra of this distribution that requires a package importable as `module`."""
    from importlib.metadata import PackageNotFoundError, requires

    try:
        requirements = requires(DISTRIBUTION) or []
    except PackageNotFoundError:
        return None
    for req in requirements:
        name = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)", req)
        extra = re.search(r"""extra\s*==\s*["']([^"']+)["']""", req)
        if name and extra and re.sub(r"[-_.]+", "_", name.group(1)).lower() == module.lower():
            return extra.group(1)
    return None


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown and not getattr(args, "accepts_any_arguments", False):
        args = parser.parse_args(argv)  # argparse's own error for the arguments it does not know (exit 2)
    try:
        return args.func(args)
    except ModuleNotFoundError as exc:
        hint = missing_module_hint(exc)
        if hint is None:
            raise
        return _cannot_run(args.command, hint)


def entry() -> None:
    """The `v2i` console script: main(), then leave without running native libraries' exit code.

    Some native teardown (zenoh's runtime threads, Mesa EGL, the FMUs' shared
    objects unloaded by dlclose) was seen to abort with a corrupted heap after a
    run had finished and written everything; the run's outcome is the exit
    status, so nothing is lost by skipping that teardown.
    """
    import logging
    import os

    code = main()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":  # pragma: no cover
    entry()
