"""Scenario files (TOML): load, resolve FMUs, and validate before anything runs.

A scenario names FMU instances with their parameters and start values,
connections `"a.out -> b.in"`, time settings and what to record. Every
problem found is reported at once, each with its key and what was expected,
so a bad file is fixed in one pass and never half-runs.
"""
from __future__ import annotations

import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from master.errors import ScenarioError
from master.scenario.overrides import Override, OverrideError, annotate, apply_overrides, parse_overrides
from master.fmi.variables import check_setting, describe_type, family, shape, unsupported_reason
from master.scenario.input_file import read_input
from master.scenario.sections import SectionContext, read_sections, section_keys
from master.scenario.conditions import COLLISION, ConditionError, compile_condition, signals_of
from master.scenario.tables import Table, deep_merge, suggest

MODES = ("lockstep", "realtime")
ORDERINGS = ("jacobi", "gauss-seidel")
OVERRUN_POLICIES = ("catch-up", "skip", "slip", "abort")
_CORE_KEYS = ("scenario", "time", "fmus", "connections", "record")  # the rest: master.scenario.sections
_TOP_KEYS = _CORE_KEYS + section_keys()
# an unknown key in a core table that is a top-level key was most likely written after a [table] header
_MOVED = {k: f"in TOML a key after a [table] header belongs to that table: move `{k} = ...` above the first [table]"
          for k in _TOP_KEYS}
_TIME_KEYS = ("start", "stop", "step", "mode", "ordering", "rtf", "overrun", "loop_nice", "stop_on")
_INSTANCE_KEYS = ("fmu", "parameters", "start", "step_multiple", "input")
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_CONNECTION = re.compile(r"^\s*([^.\s]+)\.(\S+)\s*->\s*([^.\s]+)\.(\S+)\s*$")


@dataclass
class TimeSettings:
    start: float = 0.0
    stop: float = 10.0
    step: float = 0.01
    mode: str = "lockstep"
    ordering: str = "jacobi"
    rtf: float = 1.0
    overrun: str = "catch-up"
    loop_nice: int = -10  # realtime: the loop thread's nice value (master.run.pacing.set_loop_nice)
    stop_on: tuple[str, ...] = ()  # "collision" and conditions over signals (master.scenario.conditions)

    @property
    def n_steps(self) -> int:
        return round((self.stop - self.start) / self.step)


@dataclass
class Instance:
    name: str
    fmu: str  # as written in the file
    path: Path  # resolved .fmu file
    model_description: Any  # fmpy ModelDescription
    parameters: dict[str, Any] = field(default_factory=dict)
    start: dict[str, Any] = field(default_factory=dict)
    step_multiple: int = 1
    input: Any = None  # master.scenario.input_file.InputTable: inputs driven from a CSV file

    @property
    def variables(self) -> dict[str, Any]:
        return {v.name: v for v in self.model_description.modelVariables}


@dataclass(frozen=True)
class Connection:
    src: str
    src_var: str
    dst: str
    dst_var: str

    def __str__(self) -> str:
        return f"{self.src}.{self.src_var} -> {self.dst}.{self.dst_var}"


@dataclass
class Scenario:
    path: Path
    name: str
    description: str
    time: TimeSettings
    instances: dict[str, Instance]
    connections: list[Connection]
    record: list[tuple[str, str]]  # (instance, variable)
    raw: dict[str, Any]
    record_camera: bool = False  # [record] camera: keep every camera frame (JPEG) for the report's clip
    serial: dict[str, Any] = field(default_factory=dict)  # name -> master.links.serial_bridge.SerialSpec
    world: Any = None  # master.world.layout.WorldLayout when the file has a [world] table
    participants: Any = None  # master.links.participants.ParticipantsSpec when the file has [bridge]/[participants]
    can: Any = None  # master.links.can_bridge.CanConfig when the file has [can]
    v2x: Any = None  # master.links.radio_bridge.V2xSpec when the file has [v2x]
    pki: Any = None  # master.scenario.pki.PkiSpec when the file has [pki]
    events: Any = None  # [master.scenario.scenario_events.Event] when the file has [[events]]

    @property
    def overrides(self) -> list[str]:
        """The `--set KEY=VALUE` laid over the file (already applied; the resolved scenario lists them)."""
        meta = self.raw.get("scenario")
        items = meta.get("overrides", []) if isinstance(meta, dict) else []
        return [str(o) for o in items] if isinstance(items, list) else []

    def resolved(self) -> dict[str, Any]:
        """The scenario with defaults filled in and FMU paths resolved, for the run folder."""
        t = self.time
        return {
            "scenario": {"name": self.name, "description": self.description, "source": str(self.path),
                         **({"overrides": list(self.overrides)} if self.overrides else {})},
            "time": {"start": t.start, "stop": t.stop, "step": t.step, "mode": t.mode,
                     "ordering": t.ordering, "rtf": t.rtf, "overrun": t.overrun,
                     "loop_nice": t.loop_nice, **({"stop_on": list(t.stop_on)} if t.stop_on else {})},
            "fmus": {
                i.name: {"fmu": str(i.path), "step_multiple": i.step_multiple,
                         "parameters": dict(i.parameters), "start": dict(i.start),
                         **({"input": str(i.input.path)} if i.input is not None else {})}
                for i in self.instances.values()
            },
            "connections": [str(c) for c in self.connections],
            "record": {"variables": [f"{i}.{v}" for i, v in self.record],
                       **({"camera": True} if self.record_camera else {})},
            **({"serial": {n: s.resolved() for n, s in self.serial.items()}} if self.serial else {}),
            **({"world": self.world.resolved()} if self.world is not None else {}),
            **({"can": self.can.resolved()} if self.can is not None else {}),
            **({"v2x": self.v2x.resolved()} if self.v2x is not None else {}),
            **({"pki": self.pki.resolved()} if self.pki is not None else {}),
            **({"events": [e.describe() for e in self.events]} if self.events else {}),
            **(self.participants.resolved() if self.participants is not None else {}),
        }


def _no_co_simulation(file_name: str, md) -> str:
    """Why an FMU without a co-simulation interface cannot run, naming the interfaces it has."""
    if getattr(md, "scheduledExecution", None) is not None:
        also = " (and model exchange)" if md.modelExchange is not None else ""
        return (f"{file_name} is an FMI 3 scheduled-execution FMU{also}: its model partitions are activated by "
                "clocks the importer schedules, which this master does not support; it runs co-simulation FMUs")
    if md.modelExchange is not None:
        return f"{file_name} has no co-simulation interface (model exchange only); the master runs co-simulation FMUs"
    return f"{file_name} declares no co-simulation interface; the master runs co-simulation FMUs"


def fmu_search_dir() -> Path:
    """Where built project FMUs live: `V2I_FMU_DIR`, else a checkout's build/fmus, else the per-user cache
    (fmus.builder.default_out_dir); the same folder whatever folder the run starts in."""
    from fmus.builder import default_out_dir

    return default_out_dir()


def resolve_fmu(spec: str, base_dir: Path) -> Path:
    """An FMU file path, or a project FMU by model identifier (built on demand).

    Raises FileNotFoundError with what was tried.
    """
    if spec.endswith(".fmu") or "/" in spec or os.sep in spec:
        path = Path(spec).expanduser()
        path = path if path.is_absolute() else base_dir / path
        if not path.is_file():
            raise FileNotFoundError(f"FMU file not found: {path}")
        return path.resolve()
    built = fmu_search_dir() / f"{spec}.fmu"
    from fmus.builder import project_fmu_path

    path = project_fmu_path(spec, fmu_search_dir())
    if path is not None:
        return path.resolve()
    if built.is_file():
        return built.resolve()
    from fmus.builder import discover

    known = ", ".join(s.model_identifier for s in discover())
    raise FileNotFoundError(f"no FMU named {spec!r}: not a file, not a project FMU (project FMUs: {known})")


def load_scenario_or_report(path: str | os.PathLike, overrides: Sequence[str | Override] = ()) -> Scenario | None:
    """For the CLI commands: the scenario, or None after printing why it could not be loaded
    (the caller exits 2)."""
    import sys

    try:
        return load_scenario(path, overrides)
    except ScenarioError as exc:
        print(exc, file=sys.stderr)
        return None


def load_scenario(path: str | os.PathLike, overrides: Sequence[str | Override] = ()) -> Scenario:
    """Parse and validate a scenario file; raises ScenarioError listing every problem.

    `overrides` (`KEY=VALUE` texts or master.scenario.overrides.Override) are laid over the file after its
    `extends` (master.scenario.overrides); the merged scenario is then validated as a whole, and a problem
    about an overridden key names the `--set` it came from."""
    path = Path(path)
    raw = read_raw(path)
    if not overrides:
        return _Validator(path, raw).validate()
    try:
        texts = parse_overrides(o for o in overrides if not isinstance(o, Override))
        parsed = [o if isinstance(o, Override) else texts.pop(0) for o in overrides]
        raw, where = apply_overrides(raw, parsed)
    except OverrideError as exc:
        raise ScenarioError(path, exc.problems) from None
    meta = raw.setdefault("scenario", {})
    if isinstance(meta, dict):  # the resolved scenario lists them (after those of a resolved file run again)
        before = meta.get("overrides")
        meta["overrides"] = (before if isinstance(before, list) else []) + [o.text for o in parsed]
    try:
        return _Validator(path, raw).validate()
    except ScenarioError as exc:
        raise ScenarioError(path, annotate(exc.problems, where)) from None


def read_raw(path: Path) -> dict[str, Any]:
    """The file's tables with those of the scenario it `extends`, unvalidated (ScenarioError when unreadable)."""
    if path.suffix.lower() == ".ssp":  # an SSP package: its system as these tables (master.scenario.ssp_import)
        from master.scenario.ssp_import import read_ssp

        return read_ssp(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ScenarioError(path, [f"cannot read file: {exc.strerror or exc}"]) from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(path, [f"not valid TOML: {exc}"]) from None
    return with_base(path, raw)


def with_base(path: Path, raw: dict[str, Any], chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The file's tables laid over those of the scenario it `extends` ([scenario] extends = "base.toml").

    Tables merge key by key, recursively; any other value (numbers, strings, lists, arrays of tables)
    replaces the base's. So a variant names only what differs, e.g. ima_no_cps.toml switches the RSU
    app off (`[participants.rsu] enabled = false`) and nothing else can drift between the two files.
    The base's relative paths are read from the extending file's folder: keep the two in one folder.
    """
    meta = raw.get("scenario")
    base_name = meta.get("extends") if isinstance(meta, dict) else None
    if base_name is None:
        return raw
    if not isinstance(base_name, str) or not base_name:
        raise ScenarioError(path, [f"scenario.extends: expected the path of a scenario file, got {base_name!r}"])
    base = Path(base_name).expanduser()
    base = (base if base.is_absolute() else path.parent / base).resolve()
    chain = chain + (path.resolve(),)
    if base in chain:
        raise ScenarioError(path, [f"scenario.extends: {base_name!r} extends this file again "
                                   f"({' -> '.join(p.name for p in chain + (base,))})"])
    try:
        base_raw = tomllib.loads(base.read_text())
    except OSError as exc:
        raise ScenarioError(path, [f"scenario.extends: cannot read {base}: {exc.strerror or exc}"]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(path, [f"scenario.extends: {base} is not valid TOML: {exc}"]) from None
    merged = deep_merge(with_base(base, base_raw, chain), raw)
    merged["scenario"] = {k: v for k, v in merged["scenario"].items() if k != "extends"}
    return merged


class _Validator:
    def __init__(self, path: Path, raw: dict[str, Any]):
        self.path, self.raw = path, raw
        self.problems: list[str] = []

    def problem(self, key: str, message: str) -> None:
        self.problems.append(f"{key}: {message}")

    def validate(self) -> Scenario:
        """The core tables here, then each section present through its own reader (master.scenario.sections)."""
        raw = self.raw
        top = Table(raw, "", self.problem)
        top.unknown_keys(_TOP_KEYS)
        meta = top.sub("scenario")
        meta.unknown_keys(("name", "description", "source", "overrides"), _MOVED)  # source, overrides: as written
                                                                                  # by resolved(), informative
        name = meta.get("name", self.path.stem)
        description = meta.get("description", "")
        for key, value in (("name", name), ("description", description)):
            if not isinstance(value, str):
                meta.problem(key, f"expected a string, got {type(value).__name__}")
        time = self.time_settings(top.sub("time"))
        instances = self.instances(top.sub("fmus"), time)
        connections = self.connections(raw.get("connections", []), instances)
        record_table = top.sub("record")
        record = self.record(record_table, instances)
        record_camera = record_table.boolean("camera", False)
        self.stop_conditions(time, instances)
        sections = read_sections(SectionContext(self.path, raw, instances, connections, time, self.problem))
        if record_camera and "world" not in raw:
            self.problem("record.camera", "needs a [world] with cameras to record")
        if COLLISION in time.stop_on and not isinstance(raw.get("world"), dict):
            self.problem("time.stop_on", "\"collision\" needs a [world] whose vehicles give the footprints")
        if self.problems:
            raise ScenarioError(self.path, self.problems)
        return Scenario(self.path, str(name), str(description), time, instances, connections, record, raw,
                        record_camera, **sections)

    def stop_conditions(self, time: TimeSettings, instances: dict[str, Instance]) -> None:
        """Each `[time] stop_on` entry: the word "collision" or a condition over signals that compiles."""
        signals, positions = signals_of(instances)
        for i, text in enumerate(time.stop_on):
            if text == COLLISION:
                continue
            try:
                compile_condition(text, signals, positions)
            except ConditionError as exc:
                self.problem(f"time.stop_on[{i}]", str(exc))

    def time_settings(self, t: Table) -> TimeSettings:
        t.unknown_keys(_TIME_KEYS, _MOVED)
        d = TimeSettings()
        s = TimeSettings(
            start=t.number("start", d.start),
            stop=t.number("stop", d.stop),
            step=t.number("step", d.step, low=0, low_open=True),
            mode=t.choice("mode", MODES, d.mode),
            ordering=t.choice("ordering", ORDERINGS, d.ordering),
            rtf=t.number("rtf", d.rtf, low=0, low_open=True),
            overrun=t.choice("overrun", OVERRUN_POLICIES, d.overrun),
            loop_nice=t.number("loop_nice", d.loop_nice, low=-20, high=19, integer=True),
            stop_on=tuple(t.strings("stop_on", [], one=True, expected='a list such as ["collision", "cav.v < 0.1"]')
                          or ()),
        )
        if s.stop <= s.start:
            t.problem("stop", f"must be greater than time.start ({s.start}), got {s.stop}")
        elif abs((s.stop - s.start) / s.step - s.n_steps) > 1e-6:
            t.problem("stop", f"stop - start = {s.stop - s.start} s is not a whole number of {s.step} s steps")
        return s

    def instances(self, fmus: Table, time: TimeSettings) -> dict[str, Instance]:
        from fmpy import platform as fmpy_platform
        from fmpy import platform_tuple as fmpy_platform_tuple
        from fmpy import read_model_description, supported_platforms

        if not fmus.raw:
            fmus.problem(None, "no FMU instances: add at least one [fmus.NAME] table")
        result = {}
        for name in fmus.raw:
            key = fmus.key(name)
            if not _NAME.match(name):
                fmus.problem(name, "instance names must be identifiers (letters, digits, _; no dots)")
                continue
            spec = fmus.sub(name)
            if not spec.ok:
                continue
            spec.unknown_keys(_INSTANCE_KEYS, _MOVED)
            fmu = spec.string("fmu", required=True,
                              expected="an FMU file path or a project FMU name (e.g. VehicleDynamics)")
            if fmu is None:
                continue
            try:
                fmu_path = resolve_fmu(fmu, self.path.parent)
                md = read_model_description(str(fmu_path), validate=False)
            except Exception as exc:  # missing file, bad zip, bad XML: all the user's to fix
                self.problem(f"{key}.fmu", f"{exc}")
                continue
            if md.coSimulation is None:
                self.problem(f"{key}.fmu", _no_co_simulation(fmu_path.name, md))
                continue
            platforms = supported_platforms(str(fmu_path))
            if fmpy_platform not in platforms and f"{fmpy_platform_tuple}" not in platforms:
                self.problem(f"{key}.fmu", f"{fmu_path.name} has no binary for this platform ({fmpy_platform}); "
                                           f"it supports: {', '.join(platforms) or 'none'}")
                continue
            multiple = spec.number("step_multiple", 1, low=1, integer=True, expected="an integer >= 1")
            if time.n_steps % multiple:
                spec.problem("step_multiple", f"{multiple} does not divide the run's {time.n_steps} steps")
            if md.coSimulation.canBeInstantiatedOnlyOncePerProcess and any(
                    other.path == fmu_path for other in result.values()):
                self.problem(key, f"{fmu_path.name} declares canBeInstantiatedOnlyOncePerProcess; "
                                  "it cannot have a second instance in this run")
                continue
            inst = Instance(name, fmu, fmu_path, md, step_multiple=multiple)
            inst.parameters = self.values(inst, spec.sub("parameters"), parameters=True)
            inst.start = self.values(inst, spec.sub("start"), parameters=False)
            inst.input = read_input(spec, inst.variables, fmu_path.name, md.fmiVersion.startswith("3"),
                                    self.path.parent, time.start)
            result[name] = inst
        return result

    def values(self, inst: Instance, table: Table, parameters: bool) -> dict[str, Any]:
        variables, accepted, prefix = inst.variables, {}, table.prefix
        for var_name, value in table.raw.items():
            key = table.key(var_name)
            var = variables.get(var_name)
            if var is None:
                self.problem(key, f"unknown variable {var_name!r} of {inst.path.name} ({suggest(var_name, variables)})")
                continue
            if unsupported_reason(var):
                self.problem(key, unsupported_reason(var))
                continue
            if parameters and var.causality != "parameter":
                self.problem(key, f"{var_name!r} has causality {var.causality}, not parameter "
                                  f"(set inputs under {prefix.rsplit('.', 1)[0]}.start)")
                continue
            if not parameters:
                if var.causality == "parameter":
                    self.problem(key, f"{var_name!r} is a parameter: set it under {prefix.rsplit('.', 1)[0]}.parameters")
                    continue
                if var.causality != "input" and var.initial not in ("exact", "approx"):
                    self.problem(key, f"{var_name!r} has causality {var.causality} and no settable start value")
                    continue
            if var.variability == "constant":
                self.problem(key, f"{var_name!r} is a constant and cannot be set")
                continue
            reason = check_setting(var, value, inst.model_description.fmiVersion.startswith("3"))
            if reason:
                self.problem(key, reason)
                continue
            accepted[var_name] = value
        return accepted

    def connections(self, items: Any, instances: dict[str, Instance]) -> list[Connection]:
        if not isinstance(items, list):
            self.problem("connections", f"expected a list of \"a.out -> b.in\" strings, got {type(items).__name__}")
            return []
        result = []
        targets = {(name, column): f"the input file {inst.input.path.name}"  # an input has one driver
                   for name, inst in instances.items() if inst.input is not None for column in inst.input.names}
        for i, text in enumerate(items):
            key = f"connections[{i}]"
            match = _CONNECTION.match(text) if isinstance(text, str) else None
            if not match:
                self.problem(key, f"expected \"instance.output -> instance.input\", got {text!r}")
                continue
            conn = Connection(*match.groups())
            src = self.endpoint(key, conn.src, conn.src_var, instances, "output")
            dst = self.endpoint(key, conn.dst, conn.dst_var, instances, "input")
            if src is None or dst is None:
                continue
            if family(src.type) != family(dst.type):
                self.problem(key, f"type mismatch: {conn.src}.{conn.src_var} is {src.type}, "
                                  f"{conn.dst}.{conn.dst_var} is {dst.type}")
                continue
            if shape(src) != shape(dst):
                self.problem(key, f"size mismatch: {conn.src}.{conn.src_var} is {describe_type(src)}, "
                                  f"{conn.dst}.{conn.dst_var} is {describe_type(dst)}")
                continue
            target = (conn.dst, conn.dst_var)
            if target in targets:
                self.problem(key, f"{conn.dst}.{conn.dst_var} is already driven by {targets[target]}")
                continue
            targets[target] = str(conn)
            result.append(conn)
        return result

    def endpoint(self, key: str, inst_name: str, var_name: str, instances: dict[str, Instance], causality: str):
        inst = instances.get(inst_name)
        if inst is None:
            self.problem(key, f"unknown instance {inst_name!r} (instances: {', '.join(instances) or 'none'})")
            return None
        var = inst.variables.get(var_name)
        if var is None:
            self.problem(key, f"unknown variable {inst_name}.{var_name} ({suggest(var_name, inst.variables)})")
            return None
        if unsupported_reason(var):
            self.problem(key, unsupported_reason(var))
            return None
        if var.causality != causality:
            side = "source" if causality == "output" else "target"
            self.problem(key, f"causality mismatch: {inst_name}.{var_name} is {var.causality}, "
                              f"a connection {side} must be an {causality}")
            return None
        return var

    def record(self, table: Table, instances: dict[str, Instance]) -> list[tuple[str, str]]:
        table.unknown_keys(("variables", "camera"), _MOVED)
        patterns = table.get("variables", [f"{name}.*" for name in instances])
        if not isinstance(patterns, list) or not all(isinstance(p, str) for p in patterns):
            self.problem("record.variables", "expected a list of \"instance.variable\" or \"instance.*\" strings")
            return []
        chosen: list[tuple[str, str]] = []
        for i, pattern in enumerate(patterns):
            key = f"record.variables[{i}]"
            inst_name, _, var_name = pattern.partition(".")
            inst = instances.get(inst_name)
            if inst is None:
                self.problem(key, f"unknown instance {inst_name!r} in {pattern!r}")
                continue
            if var_name == "*":  # every output the master can record; arrays, Binary, Clock, String left out
                names = [v.name for v in inst.model_description.modelVariables
                         if v.causality == "output" and not unsupported_reason(v) and family(v.type) != "string"]
            elif var_name in inst.variables:
                var = inst.variables[var_name]
                reason = unsupported_reason(var) or (
                    f"{var_name!r} is a String; only numeric variables are recorded"
                    if family(var.type) == "string" else None)
                if reason:
                    self.problem(key, reason)
                    continue
                names = [var_name]
            else:
                self.problem(key, f"unknown variable {pattern!r} ({suggest(var_name, inst.variables)})")
                continue
            for n in names:
                if (inst_name, n) not in chosen:
                    chosen.append((inst_name, n))
        return chosen

