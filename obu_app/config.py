"""The OBU app's configuration: a TOML file of a few tables, every problem named by its key.

    [app]      name, station, vehicle (whose GNSS fixes are its position), role, join_timeout_s
    [bus]      transport, prefix, connect (default: what the master puts in the environment)
    [security] mode (signed | unsecured), pki_dir, credential (default: the station), trust_anchor
    [evsp]     vehicle_id, role, request_id, horizon_s, renew_s, duration_s, through_m, cancel_repeats

Paths are relative to the file.
"""
from __future__ import annotations

import dataclasses
import difflib
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from obu_app.core import EvsConfig


class ConfigError(ValueError):
    def __init__(self, problems: list[str]):
        super().__init__("; ".join(problems))
        self.problems = problems


@dataclass
class AppSection:
    name: str = "ev_obu"
    station: str | None = None
    vehicle: str = "ev"
    role: str = "obu_app"
    join_timeout_s: float = 30.0


@dataclass
class BusSection:
    transport: str | None = None
    prefix: str | None = None
    connect: list[str] = field(default_factory=list)


@dataclass
class SecuritySection:
    mode: str = "signed"
    pki_dir: str | None = None
    credential: str | None = None
    trust_anchor: str | None = None
    max_age_s: float = 0.5


@dataclass
class ObuConfig:
    app: AppSection = field(default_factory=AppSection)
    bus: BusSection = field(default_factory=BusSection)
    security: SecuritySection = field(default_factory=SecuritySection)
    evsp: EvsConfig = field(default_factory=EvsConfig)
    base: Path = Path(".")

    def path(self, value: str | None) -> Path | None:
        return None if value is None else (self.base / value)

    @property
    def station(self) -> str:
        return self.app.station or self.app.name


def _fill(obj, table: dict, where: str, problems: list[str]) -> None:
    names = [f.name for f in dataclasses.fields(obj)]
    for key, value in table.items():
        if key not in names:
            near = difflib.get_close_matches(key, names, 1)
            problems.append(f"{where}.{key}: unknown key" + (f" (did you mean {where}.{near[0]}?)" if near else
                                                              f" (known: {', '.join(names)})"))
            continue
        setattr(obj, key, value)


def build(tables: dict, base: Path = Path(".")) -> ObuConfig:
    cfg, problems = ObuConfig(base=base), []
    sections = {"app": cfg.app, "bus": cfg.bus, "security": cfg.security, "evsp": cfg.evsp}
    for name, table in tables.items():
        if name not in sections or not isinstance(table, dict):
            near = difflib.get_close_matches(name, list(sections), 1)
            problems.append(f"[{name}]: unknown table" + (f" (did you mean [{near[0]}]?)" if near else
                                                          f" (known: {', '.join(sections)})"))
            continue
        _fill(sections[name], table, name, problems)
    if cfg.security.mode not in ("signed", "unsecured"):
        problems.append(f"security.mode = {cfg.security.mode!r}: must be signed or unsecured")
    try:
        cfg.evsp.validate()
    except ValueError as exc:
        problems.append(str(exc))
    if problems:
        raise ConfigError(problems)
    return cfg


def read(path: str | Path) -> ObuConfig:
    path = Path(path)
    try:
        tables = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError([f"{path}: {exc}"]) from None
    return build(tables, path.parent)
