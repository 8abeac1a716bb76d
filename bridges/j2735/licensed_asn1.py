"""Load a user's licensed J2735 ASN.1 files as asn1tools can compile them, without editing the files.

SAE distributes the ASN.1; the project may not, so it cannot fix the text once
and ship it. What stops asn1tools 0.169 on the files as distributed is fixed
here, in memory, each time they are loaded:

* a byte-order mark at the start of a file (the parser sees U+FEFF as a
  character and stops): the text is read as UTF-8 with the mark dropped, and a
  mark anywhere else (files joined by hand) is dropped too;
* module-prefixed references, `Module.Name` (2016: `ITIS.ITIScodes`,
  `REGION.Reg-BasicSafetyMessage`, and `DSRC.REG-EXT-ID-AND-TYPE` as the
  class of an object set, which the parser refuses outright, asn1tools issue
  176): each becomes the plain `Name`, imported from `Module` into the module
  that uses it (added to that module's IMPORTS, merged into an existing
  `FROM Module` group). When the plain name would mean something else there
  (the module defines a `Name` of its own, or imports one from elsewhere: the
  2016 AddGrpB and DSRC both define `TimeMark`, `Angle`, `Elevation`), an
  alias `Name-from-Module` is defined in `Module` and imported instead.

The same type name in two modules needs no change to the text: asn1tools
keeps both and follows each module's IMPORTS; the codec looks its message
types up the same way (codec.py, `_resolve`). Comments are dropped from the
text handed to asn1tools (they carry no meaning to a codec). `notes` says what
was changed, file by file, for the user to read.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from asn1tools.parser import ParseSyntaxException, ignore_comments

from bridges.j2735.errors import J2735Error

BOM = "\ufeff"
_NAME = r"[A-Za-z][A-Za-z0-9]*(?:-[A-Za-z0-9]+)*"
_MODULE = re.compile(r"(?P<name>[A-Z][A-Za-z0-9]*(?:-[A-Za-z0-9]+)*)\s*(?:\{[^{}]*\}\s*)?DEFINITIONS\b"
                     r"[^:]*::=\s*BEGIN(?![\w-])(?P<body>.*?)(?<![\w-])END(?![\w-])", re.S)
# An assignment: `Name ::=`, `Name {Params} ::=`, `name Type ::=`, `Set CLASS ::=` (the governor may be prefixed).
_ASSIGNMENT = re.compile(rf"(?:^|\bBEGIN\b|;)\s*(?P<name>{_NAME})\s*(?P<params>\{{[^{{}}]*\}}\s*)?"
                         rf"(?P<governor>[A-Z][A-Za-z0-9.-]*\s*)?::=", re.M)
_IMPORTS = re.compile(r"\bIMPORTS\b(?P<list>.*?);", re.S)
_FROM = re.compile(rf"\bFROM\s+(?P<module>{_NAME})(?:\s*\{{[^{{}}]*\}})?(?:\s+WITH\s+(?:SUCCESSORS|DESCENDANTS))?")
_EXPORTS = re.compile(r"\bEXPORTS\b.*?;", re.S)


@dataclass
class _Module:
    name: str
    body: str
    defined: dict[str, str] = field(default_factory=dict)   # name -> governor ('' for a type)
    imports: dict[str, str] = field(default_factory=dict)   # name -> module it is imported from
    wanted: dict[str, list[str]] = field(default_factory=dict)  # module -> names to add to IMPORTS
    aliases: list[tuple[str, str]] = field(default_factory=list)  # (alias, name) to define in this module
    aliases_written: int = 0


def read_text(path: Path) -> tuple[str, list[str]]:
    """A file's text (UTF-8, or UTF-16 when it starts with that mark; invalid bytes replaced) without
    byte-order marks, and what was dropped."""
    raw = Path(path).read_bytes()
    utf16 = raw[:2] in (b"\xff\xfe", b"\xfe\xff")
    text = raw.decode("utf-16" if utf16 else "utf-8", errors="replace")
    notes = [f"{Path(path).name}: read as UTF-16"] if utf16 else []
    if BOM in text:
        notes.append(f"{Path(path).name}: dropped {text.count(BOM)} byte-order mark(s)")
        text = text.replace(BOM, "")
    if "\ufffd" in text and b"\xef\xbf\xbd" not in raw:
        notes.append(f"{Path(path).name}: bytes that are not UTF-8 read as U+FFFD")
    return text if text.endswith("\n") else text + "\n", notes


def load(paths: list[Path]) -> tuple[str, list[str]]:
    """The text of all `paths` as one ASN.1 string asn1tools can parse, and notes on what was changed."""
    notes: list[str] = []
    chunks = []
    for path in paths:
        text, file_notes = read_text(path)
        notes += file_notes
        try:
            chunks.append(ignore_comments(text))
        except ParseSyntaxException as exc:  # an unterminated /* comment
            raise J2735Error(f"{Path(path).name}: {exc.msg} (line {exc.lineno})") from None
    text, prefix_notes = qualify_references("\n".join(chunks))
    return text, notes + prefix_notes


def qualify_references(text: str) -> tuple[str, list[str]]:
    """`text` (without comments) with every `Module.Name` replaced by an imported `Name` (or an alias)."""
    modules = {m.group("name"): _Module(m.group("name"), m.group("body")) for m in _MODULE.finditer(text)}
    if not modules:
        return text, []
    for module in modules.values():
        _scan(module)
    prefixed = re.compile(rf"(?<![\w.&@-])(?P<module>{'|'.join(map(re.escape, modules))})\.(?P<name>{_NAME})")
    notes: list[str] = []

    def unqualify(module: _Module, chunk: str) -> str:
        return prefixed.sub(lambda m: _unqualify(module, modules, m, notes), chunk)

    for module in modules.values():
        module.body = unqualify(module, module.body)
    pending = True
    while pending:  # an alias's definition may itself name a prefixed governor, which may need an alias
        pending = False
        for module in modules.values():
            new = module.aliases[module.aliases_written:]
            if new:
                module.aliases_written = len(module.aliases)
                module.body = module.body.rstrip() + "\n\n" + unqualify(module, _alias_lines(module, new))
                pending = True
    for module in modules.values():
        _add_imports(module)

    def rebuilt(m: re.Match) -> str:
        whole, at = m.group(0), m.start()
        return whole[:m.start("body") - at] + modules[m.group("name")].body + whole[m.end("body") - at:]

    return _MODULE.sub(rebuilt, text), notes


def _scan(module: _Module) -> None:
    imports = _IMPORTS.search(module.body)
    if imports:
        start = 0
        for group in _FROM.finditer(imports.group("list")):
            for symbol in imports.group("list")[start:group.start()].split(","):
                symbol = symbol.replace("{", " ").replace("}", " ").strip()
                if symbol:
                    module.imports[symbol] = group.group("module")
            start = group.end()
    for m in _ASSIGNMENT.finditer(_IMPORTS.sub(" ", module.body)):
        module.defined[m.group("name")] = (m.group("governor") or "").strip()


def _unqualify(module: _Module, modules: dict[str, _Module], m: re.Match, notes: list[str]) -> str:
    source, name = m.group("module"), m.group("name")
    if source == module.name:
        return name
    local = name in module.defined or module.imports.get(name, source) != source
    if not local:
        if name not in module.imports:
            module.imports[name] = source
            module.wanted.setdefault(source, []).append(name)
            notes.append(f"{module.name}: {source}.{name} -> {name}, imported from {source}")
        return name
    target = modules[source]
    alias = next((a for a, n in target.aliases if n == name), None)
    if alias is None:
        alias = f"{name}-from-{source}"
        while alias in target.defined or alias in module.defined:
            alias += "-x"
        target.aliases.append((alias, name))
        target.defined[alias] = target.defined.get(name, "")
    if alias not in module.imports:
        module.imports[alias] = source
        module.wanted.setdefault(source, []).append(alias)
        notes.append(f"{module.name}: {source}.{name} -> {alias} (the module has its own {name}), "
                     f"defined in {source} and imported")
    return alias


def _alias_lines(module: _Module, aliases: list[tuple[str, str]]) -> str:
    """`Alias ::= Name` (a type), `alias Type ::= name` (a value), `Alias CLASS ::= { Name }` (a set)."""
    lines = []
    for alias, name in aliases:
        governor = module.defined.get(name, "")
        if not governor:
            lines.append(f"{alias} ::= {name}")
        elif name[0].islower():
            lines.append(f"{alias} {governor} ::= {name}")
        else:
            lines.append(f"{alias} {governor} ::= {{ {name} }}")
    return "\n".join(lines) + "\n"


def _add_imports(module: _Module) -> None:
    if not module.wanted:
        return
    imports = _IMPORTS.search(module.body)
    if imports is None:
        clause = "IMPORTS " + " ".join(f"{', '.join(names)} FROM {source}"
                                      for source, names in module.wanted.items()) + ";\n"
        exports = _EXPORTS.search(module.body)
        at = exports.end() if exports else 0
        module.body = module.body[:at] + "\n" + clause + module.body[at:]
        return
    listing = imports.group("list")
    for source, names in module.wanted.items():
        group = next((g for g in _FROM.finditer(listing) if g.group("module") == source), None)
        if group is None:
            listing = listing.rstrip() + f"\n   {', '.join(names)} FROM {source}"
        else:
            listing = listing[:group.start()].rstrip() + f", {', '.join(names)} " + listing[group.start():]
    module.body = module.body[:imports.start("list")] + listing + module.body[imports.end("list"):]
