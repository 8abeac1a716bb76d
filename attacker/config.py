"""The attacker's configuration: a TOML file, flags on top; every problem reported at once, by key.

    [app]
    name = "attacker"            # participant name (default $V2I_NAME, else "attacker")
    station = "attacker"         # its V2X station, [v2x.stations.NAME] of the scenario (default: the name)
    seed = 1                     # ghost ids and flood bytes follow it
    frame_log = "frames.jsonl"   # optional: one line per frame sent {seq, t, attack, bytes}
    [keys]
    pki_dir = "../keys"          # the scenario CA, only to issue the stolen certificate when it is missing
    stolen_dir = "../keys/stolen"
    [[attacks]]
    kind = "ghost-unsigned"      # attacker.attacks.ATTACKS; the table's other keys are its parameters
    start_s = 1.0
    [[attacks]]
    kind = "flood"
    label = "flood-1"            # optional: the name its counts go under (default: the kind, #2... if repeated)
    rate_hz = 500.0

Paths in a file are relative to the file; paths given as flags to the
working directory. `--attack "KIND: key = value, ..."` adds an attack from
the command line (the part after the colon is a TOML inline table's body).
"""
from __future__ import annotations

import difflib
import math
import os
import tomllib
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

from attacker.attacks import ATTACKS

TRANSPORTS = ("zenoh", "udp", "memory")


class ConfigError(ValueError):
    """Every problem of a configuration, each as (key, reason)."""

    def __init__(self, problems: list[tuple[str, str]]):
        self.problems = problems
        super().__init__("\n".join(f"{k}: {why}" for k, why in problems))


@dataclass
class AppSection:
    name: str = ""
    station: str = ""
    role: str = "attacker"
    seed: int = 0
    join_timeout_s: float = 60.0
    frame_log: str = ""


@dataclass
class BusSection:
    transport: str = ""
    prefix: str = ""
    connect: list = field(default_factory=list)


@dataclass
class KeysSection:
    pki_dir: str = ""
    stolen_dir: str = ""


@dataclass
class AttackSpec:
    label: str
    kind: str
    params: Any


@dataclass
class AttackerConfig:
    app: AppSection = field(default_factory=AppSection)
    bus: BusSection = field(default_factory=BusSection)
    keys: KeysSection = field(default_factory=KeysSection)
    attacks: list[AttackSpec] = field(default_factory=list)

    def envelopes_needed(self) -> set[str]:
        return {ATTACKS[a.kind].envelope for a in self.attacks} - {None}

    def to_dict(self) -> dict[str, Any]:
        def plain(obj):
            return {f.name: getattr(obj, f.name) for f in fields(obj)}
        return {"app": plain(self.app), "bus": plain(self.bus), "keys": plain(self.keys),
                "attacks": [{"label": a.label, "kind": a.kind, **plain(a.params)} for a in self.attacks]}


SECTIONS = {"app": AppSection, "bus": BusSection, "keys": KeysSection}
PATH_KEYS = (("keys", "pki_dir"), ("keys", "stolen_dir"), ("app", "frame_log"))


def did_you_mean(word: str, options) -> str:
    close = difflib.get_close_matches(str(word), list(options), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def read_toml(path: str | Path) -> dict[str, Any]:
    """A config file, its relative paths made relative to the file; ConfigError naming the file if unreadable."""
    path = Path(path)
    try:
        tables = tomllib.loads(path.read_text())
    except OSError as exc:
        raise ConfigError([("--config", f"cannot read {str(path)!r}: {exc.strerror}")]) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError([("--config", f"{str(path)!r} is not valid TOML: {exc}")]) from None
    base = path.resolve().parent
    for section, key in PATH_KEYS:
        table = tables.get(section)
        if isinstance(table, dict) and isinstance(table.get(key), str) and table[key] \
                and not os.path.isabs(table[key]):
            table[key] = str(base / table[key])
    return tables


def parse_attack_flag(text: str) -> dict[str, Any]:
    """`KIND` or `KIND: key = value, ...` (a TOML inline table's body) as an [[attacks]] table."""
    kind, sep, body = text.partition(":")
    table: dict[str, Any] = {"kind": kind.strip()}
    if sep and body.strip():
        try:
            table.update(tomllib.loads(f"x = {{{body}}}")["x"])
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError([("--attack", f"{text!r}: expected KIND: key = value, ... (TOML values): {exc}")]) \
                from None
    return table


def build(tables: dict[str, Any], environ=os.environ) -> AttackerConfig:
    """The configuration from a file's tables (flags already merged in); ConfigError listing every problem."""
    problems: list[tuple[str, str]] = []
    cfg = AttackerConfig()
    for key in tables:
        if key not in (*SECTIONS, "attacks"):
            problems.append((key, f"unknown table{did_you_mean(key, (*SECTIONS, 'attacks'))}; expected "
                                  f"{', '.join(SECTIONS)} or [[attacks]]"))
    for name, cls in SECTIONS.items():
        setattr(cfg, name, _section(name, cls, tables.get(name, {}), problems))
    cfg.app.name = cfg.app.name or environ.get("V2I_NAME") or "attacker"
    cfg.app.station = cfg.app.station or cfg.app.name
    if cfg.bus.transport and cfg.bus.transport not in TRANSPORTS:
        problems.append(("bus.transport", f"expected one of {', '.join(TRANSPORTS)}, got {cfg.bus.transport!r}"
                                          f"{did_you_mean(cfg.bus.transport, TRANSPORTS)}"))
    attacks = tables.get("attacks", [])
    if not isinstance(attacks, list) or not all(isinstance(a, dict) for a in attacks):
        problems.append(("attacks", "expected [[attacks]] tables"))
        attacks = []
    if not attacks:
        problems.append(("attacks", f"no attack configured: add [[attacks]] kind = ... (one of "
                                    f"{', '.join(ATTACKS)}) or --attack KIND"))
    labels: set[str] = set()
    for i, table in enumerate(attacks):
        spec = _attack(f"attacks[{i}]", table, labels, problems)
        if spec is not None:
            cfg.attacks.append(spec)
            labels.add(spec.label)
    if "expired" in cfg.envelopes_needed() and not (cfg.keys.stolen_dir or cfg.keys.pki_dir):
        problems.append(("keys.stolen_dir", "ghost-expired signs with a stolen certificate: give keys.stolen_dir "
                                            "(and keys.pki_dir, the scenario CA, to issue it there when missing)"))
    if cfg.keys.pki_dir and not cfg.keys.stolen_dir:
        cfg.keys.stolen_dir = str(Path(cfg.keys.pki_dir) / "stolen")
    if problems:
        raise ConfigError(problems)
    return cfg


def _section(name: str, cls, table: Any, problems: list) -> Any:
    out = cls()
    if not isinstance(table, dict):
        problems.append((name, f"expected a table, got {table!r}"))
        return out
    known = {f.name: f for f in fields(cls)}
    for key, value in table.items():
        f = known.get(key)
        if f is None:
            problems.append((f"{name}.{key}", f"unknown key{did_you_mean(key, known)}; known: {', '.join(known)}"))
            continue
        default = f.default if f.default is not MISSING else f.default_factory()
        checked = _value(f"{name}.{key}", value, default, {}, problems)
        if checked is not None:
            setattr(out, key, checked)
    return out


def _attack(where: str, table: dict[str, Any], labels: set[str], problems: list) -> AttackSpec | None:
    kind = table.get("kind")
    if kind not in ATTACKS:
        hint = did_you_mean(kind, ATTACKS) if isinstance(kind, str) else ""
        problems.append((f"{where}.kind", f"expected one of {', '.join(ATTACKS)}, got {kind!r}{hint}"))
        return None
    cls = ATTACKS[kind].params_type
    known = {f.name: f for f in fields(cls)}
    params = cls()
    label = table.get("label", kind)
    if not isinstance(label, str) or not label:
        problems.append((f"{where}.label", f"expected a non-empty string, got {label!r}"))
        label = kind
    if "label" not in table:
        n = 2
        while label in labels:
            label, n = f"{kind}#{n}", n + 1
    elif label in labels:
        problems.append((f"{where}.label", f"{label!r} names another attack already"))
    ok = True
    for key, value in table.items():
        if key in ("kind", "label"):
            continue
        f = known.get(key)
        if f is None:
            problems.append((f"{where}.{key}", f"{kind} has no parameter {key!r}{did_you_mean(key, known)}; its "
                                               f"parameters: {', '.join(known)}"))
            ok = False
            continue
        default = f.default if f.default is not MISSING else f.default_factory()
        checked = _value(f"{where}.{key}", value, default, f.metadata, problems)
        if checked is None:
            ok = False
        else:
            setattr(params, key, checked)
    if ok and params.stop_s <= params.start_s:
        problems.append((f"{where}.stop_s", f"must be after start_s ({params.start_s:g}), got {params.stop_s:g}"))
        ok = False
    return AttackSpec(label, kind, params) if ok else None


def _value(key: str, value: Any, default: Any, meta: dict, problems: list) -> Any:
    """`value` checked against the default's type and the field's bounds; None (and a problem) if it fails."""
    if meta.get("points"):
        return _points(key, value, problems)
    kind = type(default)
    if kind is bool:
        if isinstance(value, bool):
            return value
        problems.append((key, f"expected true or false, got {value!r}"))
        return None
    if kind in (int, float):
        wrong_type = kind is int and not isinstance(value, int)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or wrong_type:
            problems.append((key, f"expected {'an integer' if kind is int else 'a number'}, got {value!r}"))
            return None
        if math.isnan(value) or (math.isinf(value) and not (key.endswith("stop_s") and value > 0)):
            problems.append((key, f"expected a finite number, got {value!r}"))
            return None
        low, high = meta.get("low"), meta.get("high")
        if low is not None and (value < low or (meta.get("low_open") and value == low)):
            problems.append((key, f"expected a number {'>' if meta.get('low_open') else '>='} {low:g}, got {value!r}"))
            return None
        if high is not None and value > high:
            problems.append((key, f"expected at most {high:g}, got {value!r}"))
            return None
        return kind(value)
    if kind is str:
        if isinstance(value, str):
            return value
        problems.append((key, f"expected a string, got {value!r}"))
        return None
    if kind is list:
        if isinstance(value, str):
            return [v.strip() for v in value.split(",") if v.strip()]
        if isinstance(value, list) and all(isinstance(v, str) for v in value):
            return list(value)
        problems.append((key, f"expected a list of strings, got {value!r}"))
        return None
    raise TypeError(f"no check for a {kind.__name__} value")  # a field type this module forgot


def _points(key: str, value: Any, problems: list) -> list | None:
    def number(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)

    if not (isinstance(value, list) and len(value) >= 2 and all(
            isinstance(p, list) and len(p) == 2 and all(number(v) for v in p) for p in value)):
        problems.append((key, f"expected at least two points [[x, y], [x, y], ...] in metres, got {value!r}"))
        return None
    if any(a == b for a, b in zip(value, value[1:])):
        problems.append((key, "consecutive points must differ"))
        return None
    return [[float(x), float(y)] for x, y in value]
