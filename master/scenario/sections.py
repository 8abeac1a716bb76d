"""The sections of a scenario file: every top-level table beyond the core, and the module that reads it.

The core (`[scenario]`, `[time]`, `[fmus.NAME]`, `connections`, `[record]`)
is read by master.scenario.loader. Each other table belongs to the module that runs
it: `[serial.NAME]` to the serial bridge, `[world]` to the world layout,
`[can]` to the CAN bridge, `[v2x]` to the radio, `[bridge]` and
`[participants.NAME]` to the participants, `[pki]` to master.scenario.pki, `[[events]]` to
master.scenario.scenario_events. The loader calls the reader of
each section present in the file, so adding a section is one line here and
one reader in its module, not another branch in the loader.

A reader is named as "module:function" and imported only when its section is
in the file: a scenario without `[world]` never imports pybullet, one without
`[can]` never python-can. Its function takes the section's raw value (for a
section of several keys, a dict of those present) and a `SectionContext`,
reports every problem through `context.problem(key, reason)` and returns what
the Scenario keeps under the section's name (None when the section was bad).
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable


@dataclass(frozen=True)
class Section:
    """One section: which top-level keys it owns and which reader, named so that nothing is imported early."""

    name: str  # the Scenario attribute that keeps what the reader returned
    keys: tuple[str, ...]  # the top-level keys it reads
    reader: str  # "module:function", function(value, context) -> spec
    requires: tuple[tuple[str, str], ...] = ()  # (top-level key, why): tables this section cannot do without

    def present(self, raw: dict[str, Any]) -> bool:
        return any(k in raw for k in self.keys)

    def value(self, raw: dict[str, Any]) -> Any:
        """What the reader is given: the raw value of its one key, or a dict of its keys present."""
        if len(self.keys) == 1:
            return raw[self.keys[0]]
        return {k: raw[k] for k in self.keys if k in raw}

    def load(self) -> Callable[[Any, SectionContext], Any]:
        """The reader function, importing its module now (only files with this section get here)."""
        module, _, function = self.reader.partition(":")
        return getattr(importlib.import_module(module), function)


@dataclass
class SectionContext:
    """What a section reader may need of the rest of the file, read by the core before it."""

    path: Path  # the scenario file
    raw: dict[str, Any]  # the whole parsed file, for checks across tables
    instances: dict[str, Any]  # name -> master.scenario.loader.Instance
    connections: list[Any]  # master.scenario.loader.Connection
    time: Any  # master.scenario.loader.TimeSettings
    problem: Callable[[str, str], None]  # the loader's collector: (dotted key, reason)

    @property
    def base_dir(self) -> Path:
        """Where relative paths in the file start from."""
        return self.path.parent

    @property
    def step(self) -> float:
        return self.time.step


# In the order the loader reads them (and lists their problems).
SECTIONS: tuple[Section, ...] = (
    Section("serial", ("serial",), "master.links.serial_bridge:read_section"),
    Section("world", ("world",), "master.world.layout:read_section"),
    Section("participants", ("bridge", "participants"), "master.links.participants:read_section"),
    Section("can", ("can",), "master.links.can_bridge:read_section"),
    Section("v2x", ("v2x",), "master.links.radio_bridge:read_section",
            requires=(("bridge", "apps transmit and receive over the bus"),)),
    Section("pki", ("pki",), "master.scenario.pki:read_section"),
    Section("events", ("events",), "master.scenario.scenario_events:read_section"),  # after the tables events act on
)


def section_keys() -> tuple[str, ...]:
    """Every top-level key a section reads."""
    return tuple(k for s in SECTIONS for k in s.keys)


def read_sections(context: SectionContext) -> dict[str, Any]:
    """Read each section present in the file: {section name: what its reader returned}."""
    raw, specs = context.raw, {}
    for section in SECTIONS:
        if not section.present(raw):
            continue
        specs[section.name] = section.load()(section.value(raw), context)
        for key, why in section.requires:
            if key not in raw:
                context.problem(section.keys[0], f"needs a [{key}] table: {why}")
    return specs
