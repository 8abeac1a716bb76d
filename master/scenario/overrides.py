"""Scenario overrides: `v2i run FILE --set KEY=VALUE`, and every point of a sweep.

An override names one value of the scenario by its dotted key, the way the
loader names keys in its problems, and gives it a new value::

    --set fmus.ev.parameters.v0=20.1          # a number
    --set v2x.channel.technology=cv2x         # a bare word: the string "cv2x"
    --set 'participants.rsu.args=["--hardware", "cpu-i7"]'
    --set 'world.cameras[rsu_cam].z=10.0'     # an element of an array of tables, by its name ...
    --set 'world.buildings=[]'                # ... or a whole array replaced
    --set 'world.buildings[0].height=30'      # ... or an element by its index

The value is a TOML literal (`20.1`, `true`, `"a b"`, `[1, 2]`, `{ detect = 0.2 }`);
only when it is not one and is a bare word (letters, digits and `_ . : / @ + -`,
e.g. `cv2x`, `tcp/127.0.0.1:7447`) does it count as that string. So `07` or
`2.4.1` are strings and `1e3` is a number; quote a string that looks like a
number (`'"30"'`).

Overrides are laid over the scenario after `[scenario] extends` is resolved,
with the same rule as `extends`: a table value is merged key by key into the
table it lands on, any other value replaces what was there. Missing tables on
the way are created, so an override may set a key the file leaves at its
default. Nothing else is checked here: the merged scenario is validated as a
whole, exactly like a file, so an unknown key or a bad value is refused with
the loader's own message and "did you mean" (and the `--set` it came from).
"""
from __future__ import annotations

import copy
import math
import re
import tomllib
from dataclasses import dataclass
from typing import Any, Iterable

from master.scenario.tables import deep_merge, did_you_mean

_BARE_WORD = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.:/@+\-]*")
_BARE_KEY = re.compile(r"[A-Za-z0-9_\-]+")
_SELECTOR = re.compile(r"\[([^\[\]]+)\]")


class OverrideError(ValueError):
    """Overrides that cannot be parsed or applied; `problems` holds one line per fault."""

    def __init__(self, problems: list[str]):
        self.problems = list(problems)
        super().__init__("\n".join(self.problems))


@dataclass(frozen=True)
class Segment:
    """One step of a key path: a table key, optionally followed by selectors into an array of tables
    (an int: the element at that index; a str: the element whose `name` it is)."""

    key: str
    selectors: tuple[int | str, ...] = ()


@dataclass(frozen=True)
class Override:
    """One `KEY=VALUE`: the parsed key path and value, and the text it was written as."""

    key: str
    path: tuple[Segment, ...]
    value: Any
    text: str

    def __str__(self) -> str:
        return self.text


# -- parsing -----------------------------------------------------------------------------------------
def parse_value(text: str) -> Any:
    """A TOML literal, or the bare word itself as a string; ValueError when it is neither."""
    try:
        doc = tomllib.loads(f"v = {text}")
    except tomllib.TOMLDecodeError:
        doc = None
    if doc is not None and list(doc) == ["v"]:
        return doc["v"]
    if _BARE_WORD.fullmatch(text):
        return text
    if not text:
        raise ValueError("no value (an empty string is '\"\"')")
    raise ValueError(f"{text!r} is neither a TOML value nor a bare word; quote a string: '\"...\"'")


def parse_key(text: str) -> tuple[Segment, ...]:
    """The segments of a dotted key such as `world.cameras[rsu_cam].z` or `v2x."channel".seed`."""
    segments: list[Segment] = []
    rest = text.strip()
    if not rest:
        raise ValueError("empty key")
    while True:
        if rest.startswith('"'):
            end = rest.find('"', 1)
            if end < 0:
                raise ValueError(f"unterminated quoted key in {text!r}")
            key, rest = rest[1:end], rest[end + 1:]
        else:
            match = _BARE_KEY.match(rest)
            if match is None:
                raise ValueError(f"expected a key (letters, digits, _ or -) at {rest!r} in {text!r}")
            key, rest = match.group(0), rest[match.end():]
        selectors: list[int | str] = []
        while rest.startswith("["):
            match = _SELECTOR.match(rest)
            if match is None:
                raise ValueError(f"expected [INDEX] or [NAME] at {rest!r} in {text!r}")
            word = match.group(1).strip().strip('"')
            selectors.append(int(word) if re.fullmatch(r"-?\d+", word) else word)
            rest = rest[match.end():]
        segments.append(Segment(key, tuple(selectors)))
        if not rest:
            return tuple(segments)
        if not rest.startswith("."):
            raise ValueError(f"expected '.' or '[' at {rest!r} in {text!r}")
        rest = rest[1:]


def parse_override(text: str) -> Override:
    """`KEY=VALUE` -> Override; ValueError saying what is wrong with it."""
    key, sep, value = text.partition("=")
    if not sep:
        raise ValueError(f"expected KEY=VALUE, got {text!r}")
    key = key.strip()
    return Override(key, parse_key(key), parse_value(value.strip()), text)


def parse_overrides(items: Iterable[str]) -> list[Override]:
    """Every `KEY=VALUE` parsed; OverrideError listing each bad one."""
    out, problems = [], []
    for item in items:
        try:
            out.append(parse_override(item))
        except ValueError as exc:
            problems.append(f"--set {item}: {exc}")
    if problems:
        raise OverrideError(problems)
    return out


def override(key: str, value: Any) -> Override:
    """An Override from a key and an already typed value (a sweep point's parameter)."""
    return Override(key, parse_key(key), value, f"{key}={toml_literal(value)}")


# -- applying ----------------------------------------------------------------------------------------
def apply_overrides(raw: dict[str, Any], overrides: Iterable[Override]) -> tuple[dict[str, Any], dict[str, str]]:
    """(a copy of `raw` with every override laid over it in order, {loader key of each override: its text}).

    The loader key names the value as the validator does (`world.cameras[0].z`
    for `world.cameras[rsu_cam].z`), so its problems can say which `--set`
    they come from. OverrideError lists every override that cannot land (a
    path through a value that is not a table, an index out of range, no element
    of that name).
    """
    out = copy.deepcopy(raw)
    where: dict[str, str] = {}
    problems: list[str] = []
    for item in overrides:
        try:
            key = _apply(out, item.path, copy.deepcopy(item.value), deep_merge)
        except ValueError as exc:
            problems.append(f"--set {item.text}: {exc}")
            continue
        where[key] = item.text
    if problems:
        raise OverrideError(problems)
    return out, where


def _apply(raw: dict[str, Any], path: tuple[Segment, ...], value: Any, merge) -> str:
    node: Any = raw
    shown: list[str] = []
    created = ""  # the first table this override had to create (for the hint when a selector then fails)
    for n, seg in enumerate(path):
        last = n == len(path) - 1
        here = ".".join(shown) or "the scenario"
        if not isinstance(node, dict):
            raise ValueError(f"{here} is {_kind(node)}, not a table: it has no key {seg.key!r}")
        shown.append(_key_text(seg.key))
        if last and not seg.selectors:
            if isinstance(value, dict) and isinstance(node.get(seg.key), dict):
                node[seg.key] = merge(node[seg.key], value)
            else:
                node[seg.key] = value
            return ".".join(shown)
        if seg.key not in node:
            if seg.selectors:
                raise ValueError(f"{'.'.join(shown)} is not in the scenario: there is no array to select from"
                                 + (created or _hint(seg.key, node)))
            if not created:
                created = f" ({'.'.join(shown)} is not in the scenario{_hint(seg.key, node)})"
            node[seg.key] = {}
        parent, slot = node, seg.key
        node = node[seg.key]
        for i, selector in enumerate(seg.selectors):
            if not isinstance(node, list):
                raise ValueError(f"{'.'.join(shown)} is {_kind(node)}, not an array: [{selector}] selects nothing")
            index = _select(node, selector, ".".join(shown))
            shown[-1] += f"[{index}]"
            parent, slot = node, index
            node = node[index]
            if last and i == len(seg.selectors) - 1:
                parent[slot] = merge(node, value) if isinstance(value, dict) and isinstance(node, dict) else value
                return ".".join(shown)
    raise AssertionError("unreachable")  # pragma: no cover


def _select(items: list[Any], selector: int | str, where: str) -> int:
    if isinstance(selector, int):
        if not -len(items) <= selector < len(items):
            raise ValueError(f"{where}[{selector}]: index out of range ({where} has {len(items)} element(s))")
        return selector % len(items)
    names = [item.get("name") for item in items if isinstance(item, dict)]
    for i, item in enumerate(items):
        if isinstance(item, dict) and item.get("name") == selector:
            return i
    hint = did_you_mean(selector, [n for n in names if isinstance(n, str)])
    listed = ", ".join(repr(n) for n in names if isinstance(n, str)) or "none named"
    raise ValueError(f"{where}[{selector}]: no element named {selector!r} (elements: {listed})"
                     + (f"; {hint}" if hint else ""))


def _hint(key: str, table: dict[str, Any]) -> str:
    hint = did_you_mean(key, [k for k in table if isinstance(k, str)])
    return f"; {hint}" if hint else ""


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def _key_text(key: str) -> str:
    return key if _BARE_KEY.fullmatch(key) else _basic_string(key)


def annotate(problems: list[str], where: dict[str, str]) -> list[str]:
    """The loader's `key: reason` problems, each about an overridden key (or one under it) followed by the
    `--set` that put the value there."""
    out = []
    for problem in problems:
        key = problem.split(": ", 1)[0]
        source = next((text for k, text in sorted(where.items(), key=lambda kv: -len(kv[0]))
                       if key == k or key.startswith(k + ".") or key.startswith(k + "[")), None)
        out.append(f"{problem} (from --set {source})" if source else problem)
    return out


# -- writing values back -----------------------------------------------------------------------------
def toml_literal(value: Any) -> str:
    """`value` as a one-line TOML literal (parse_value(toml_literal(v)) == v): how a sweep passes a
    point's parameters to `v2i run --set`."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _basic_string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_literal(v) for v in value) + "]"
    if isinstance(value, dict):
        items = ", ".join(f"{_key_text(str(k))} = {toml_literal(v)}" for k, v in value.items())
        return "{ " + items + " }" if items else "{}"
    raise TypeError(f"cannot write {type(value).__name__} {value!r} as a TOML value")


def _basic_string(text: str) -> str:
    out = ['"']
    for ch in text:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)
