"""An SSP 1.0 package read back as the tables of a scenario: `v2i run system.ssp`, `v2i validate system.ssp`.

master.scenario.loader.read_raw hands a `.ssp` file here; what comes back is the dict a
scenario TOML file would parse to (`[scenario]`, `[time]`, `[fmus.NAME]` with
parameters and start values, `connections`, `[record]`), with each FMU extracted
from the package. The scenario loader then validates it like any file, so an
SSP and the TOML it came from give the same Scenario, `--set` works on both,
and a causality or type mismatch is refused with the loader's own message.

Read: the top-level System's FMU Components (co-simulation), their Connectors,
Connections between them, ParameterBindings (inline or an .ssv file in the
package, on a Component or with hierarchical names on the System, with a
prefix), the DefaultExperiment's start and stop, and our own annotations
(master.scenario.ssp.ANNOTATION_TYPE; other tools' annotations and all geometry are
ignored). Refused, each with the element named: nested systems and SSD/SSP
components, signal dictionaries, connectors of the system itself,
transformations on connections, parameter mappings, connections between
connectors of different units, model-exchange-only components. A parameter
value whose name matches no variable is refused too (SSP would ignore it; here
a misspelt name must not silently run another experiment).

The FMUs are extracted once per package content into a cache folder
(`v2i-ssp/<hash>` in the temp folder), so the resolved scenario a run writes
names files that still exist after the run.
"""
from __future__ import annotations

import hashlib
import os
import posixpath
import tempfile
import zipfile
from pathlib import Path
from typing import Any

from lxml import etree

from master.errors import ScenarioError
from master.scenario.ssp import (ANNOTATION_TYPE, FMU_TYPE, NS, PARAMETER_SET_TYPE, RESOURCES, SSD_NAME, from_ssv,
                        schema_problems)
from master.scenario.tables import did_you_mean

_KINDS = {"input": "input", "output": "output", "parameter": "parameter",
          "calculatedParameter": "calculatedParameter"}  # connector kind -> FMI 2 causality
_LAYOUT = ("ConnectionGeometry", "Annotations")  # children of a Connection that change nothing it carries
_MASTER_ATTRS = {"step": ("step", float), "mode": ("mode", str), "ordering": ("ordering", str),
                 "rtf": ("rtf", float), "overrun": ("overrun", str)}  # v2i:Master attribute -> [time] key


def cache_root() -> Path:
    """Where packages are extracted (`V2I_SSP_CACHE`, default `<temp>/v2i-ssp`)."""
    return Path(os.environ.get("V2I_SSP_CACHE") or Path(tempfile.gettempdir()) / "v2i-ssp")


def read_ssp(path: Path) -> dict[str, Any]:
    """The scenario tables of the SSP package at `path`; ScenarioError listing every problem found."""
    reader = _Reader(path)
    raw = reader.read()
    if reader.problems:
        raise ScenarioError(path, reader.problems)
    return raw


def _children(element: etree._Element):
    """The child elements (comments and processing instructions left out)."""
    return element.iterchildren(etree.Element)


def _hint(name: str, candidates) -> str:
    candidates = list(candidates)
    return did_you_mean(name, candidates) or f"there are: {', '.join(candidates) or 'none'}"


class _Reader:
    def __init__(self, path: Path):
        self.path = path
        self.problems: list[str] = []
        self._digest: str | None = None  # of the package's bytes: names its folder in the cache
        self.failed: set[str] = set()  # components already refused: what refers to them says nothing more

    def problem(self, where: str, message: str) -> None:
        self.problems.append(f"{where}: {message}")

    # -- the package ----------------------------------------------------------------------------
    def read(self) -> dict[str, Any]:
        try:
            zf = zipfile.ZipFile(self.path)
        except OSError as exc:  # the error names the file already: say only what went wrong, as for a .toml
            self.problems.append(f"cannot read file: {exc.strerror or exc}")
            return {}
        except zipfile.BadZipFile as exc:
            self.problems.append(f"not an SSP package (an SSP is a zip file): {exc}")
            return {}
        with zf:
            names = zf.namelist()
            if SSD_NAME not in names:
                self.problem(SSD_NAME, f"missing: an SSP holds its system in {SSD_NAME} at the top of the zip "
                                       f"(the package holds: {', '.join(names) or 'nothing'})")
                return {}
            try:
                root = etree.fromstring(zf.read(SSD_NAME))
            except etree.XMLSyntaxError as exc:
                self.problem(SSD_NAME, f"not well-formed XML: {exc}")
                return {}
            for message in schema_problems(root):
                self.problem(SSD_NAME, f"breaks the SSP 1.0 schema: {message}")
            if self.problems:
                return {}
            return self.system(root, zf)

    def system(self, root: etree._Element, zf: zipfile.ZipFile) -> dict[str, Any]:
        system = root.find("ssd:System", NS)
        self.unsupported(system)
        components = {}
        for comp in system.iterfind("ssd:Elements/ssd:Component", NS):
            if comp.get("name") in components or comp.get("name") in self.failed:
                self.problem(f"Component {comp.get('name')!r}", "a second element of this name (names are unique "
                                                                "within their system)")
                continue
            found = self.component(comp, zf)
            if found is not None:
                components[comp.get("name")] = found
            else:
                self.failed.add(comp.get("name"))
        fmus = {name: c.table for name, c in components.items()}
        connections = self.connections(system, components)
        self.bindings(system, f"System {system.get('name')!r}", components, system_level=True)
        meta = {"name": root.get("name")}
        if root.get("description"):
            meta["description"] = root.get("description")
        raw: dict[str, Any] = {"scenario": meta, "time": {}, "fmus": fmus}
        if connections:
            raw["connections"] = connections
        self.experiment(root, raw, components)
        return raw

    def unsupported(self, system: etree._Element) -> None:
        """Refuse what this master cannot run, naming the element (see the module's docstring)."""
        where = f"System {system.get('name')!r}"
        for nested in system.iterfind("ssd:Elements/ssd:System", NS):
            self.problem(f"{where}: System {nested.get('name')!r}", "nested systems are not supported; "
                         "flatten the system to FMU components")
        for ref in system.iterfind("ssd:Elements/ssd:SignalDictionaryReference", NS):
            self.problem(f"{where}: SignalDictionaryReference {ref.get('name')!r}", "signal dictionaries are not "
                         "supported")
        if system.find("ssd:SignalDictionaries", NS) is not None:
            self.problem(f"{where}: SignalDictionaries", "signal dictionaries are not supported")
        for connector in system.iterfind("ssd:Connectors/ssd:Connector", NS):
            self.problem(f"{where}: Connector {connector.get('name')!r}", "connectors of the system itself are not "
                         "supported: the master has nothing outside the system to feed or read them")

    # -- components -----------------------------------------------------------------------------
    def component(self, comp: etree._Element, zf: zipfile.ZipFile) -> _Component | None:
        name, source = comp.get("name"), comp.get("source")
        where = f"Component {name!r}"
        kind = comp.get("type", FMU_TYPE)
        if kind != FMU_TYPE:
            self.problem(where, f"type {kind!r} is not supported: only FMUs ({FMU_TYPE}) are, not referenced "
                                "SSDs or SSPs")
            return None
        if comp.get("implementation", "any") == "ModelExchange":
            self.problem(where, "implementation 'ModelExchange' is not supported: the master runs FMUs as "
                                "co-simulation (use 'CoSimulation' or 'any')")
            return None
        member = self.member(where, source, zf)
        if member is None:
            return None
        fmu_path = self.extract(member, zf)
        try:
            from fmpy import read_model_description

            md = read_model_description(str(fmu_path), validate=False)
        except Exception as exc:  # noqa: BLE001 -- a bad FMU in the package: the user's to fix
            self.problem(where, f"source {source!r} is not a readable FMU: {exc}")
            return None
        found = _Component(name, fmu_path, md)
        for connector in comp.iterfind("ssd:Connectors/ssd:Connector", NS):
            self.connector(where, found, connector)
        self.bindings(comp, where, {name: found}, system_level=False)
        for annotation in comp.iterfind("ssd:Annotations/ssc:Annotation", NS):
            if annotation.get("type") == ANNOTATION_TYPE:
                self.instance_annotation(where, annotation, found)
        return found

    def member(self, where: str, source: str, zf: zipfile.ZipFile) -> str | None:
        """The zip entry a Component's source names: a relative path inside the package, nothing else."""
        member = posixpath.normpath(source) if source and "://" not in source else None
        if member is None or source.startswith("/") or member.startswith("..") or "#" in source:
            self.problem(where, f"source {source!r} is not supported: give the FMU's path inside the package "
                                f"(e.g. {RESOURCES}model.fmu)")
            return None
        names = zf.namelist()
        if member not in names:
            fmus = [n for n in names if n.endswith(".fmu")]
            self.problem(where, f"source {source!r} is not in the package ({_hint(member, fmus)})")
            return None
        return member

    def extract(self, member: str, zf: zipfile.ZipFile) -> Path:
        """The FMU's file in the cache: extracted once per package content, atomically."""
        if self._digest is None:
            self._digest = hashlib.sha256(self.path.read_bytes()).hexdigest()[:16]
        target = cache_root() / self._digest / member
        if not target.is_file():
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=".partial-")
            with os.fdopen(fd, "wb") as out:
                out.write(zf.read(member))
            os.replace(tmp, target)
        return target

    def connector(self, where: str, comp: _Component, connector: etree._Element) -> None:
        name, kind = connector.get("name"), connector.get("kind")
        var = comp.variables.get(name)
        if var is None:
            self.problem(f"{where}: Connector {name!r}", f"{comp.path.name} has no variable {name!r} "
                                                         f"({_hint(name, comp.variables)})")
            return
        if _KINDS.get(kind) != var.causality:
            self.problem(f"{where}: Connector {name!r}", f"kind {kind!r} does not match the variable's causality "
                                                         f"{var.causality!r}")
            return
        real = connector.find("ssc:Real", NS)
        comp.connectors[name] = (kind, real.get("unit") if real is not None else None)

    def instance_annotation(self, where: str, annotation: etree._Element, comp: _Component) -> None:
        for element in _children(annotation):
            if element.tag != f"{{{NS['v2i']}}}Instance" or set(element.attrib) - {"stepMultiple"}:
                self.problem(f"{where}: Annotation {ANNOTATION_TYPE!r}", f"unknown content {etree.tostring(element)!r}")
                continue
            if "stepMultiple" in element.attrib:
                try:
                    comp.table["step_multiple"] = int(element.get("stepMultiple"))
                except ValueError:
                    self.problem(f"{where}: Annotation {ANNOTATION_TYPE!r}",
                                 f"stepMultiple {element.get('stepMultiple')!r} is not an integer")

    # -- parameter bindings ---------------------------------------------------------------------
    def bindings(self, element: etree._Element, where: str, components: dict[str, _Component],
                 system_level: bool) -> None:
        """Apply the element's ParameterBindings in document order (a later one wins, as SSP says).

        On a Component names are its variables; on the System they are "component.variable". The
        System's bindings are read after every Component's, so they take precedence, as SSP says."""
        for n, binding in enumerate(element.iterfind("ssd:ParameterBindings/ssd:ParameterBinding", NS), 1):
            at = f"{where}: ParameterBinding {n}"
            if binding.find("ssd:ParameterMapping", NS) is not None:
                self.problem(at, "ParameterMapping is not supported: name the FMU variables in the parameter set")
                continue
            if binding.get("type", PARAMETER_SET_TYPE) != PARAMETER_SET_TYPE:
                self.problem(at, f"type {binding.get('type')!r} is not supported (only {PARAMETER_SET_TYPE})")
                continue
            pset = self.parameter_set(at, binding)
            if pset is None:
                continue
            prefix = binding.get("prefix", "")
            for parameter in pset.iterfind("ssv:Parameters/ssv:Parameter", NS):
                self.parameter(at, prefix + parameter.get("name"), parameter, components, system_level)

    def parameter_set(self, at: str, binding: etree._Element) -> etree._Element | None:
        source = binding.get("source")
        if source is None:
            pset = binding.find("ssd:ParameterValues/ssv:ParameterSet", NS)
            if pset is None:
                self.problem(at, "neither a source nor an inline ssv:ParameterSet")
            return pset
        if binding.get("sourceBase", "SSD") != "SSD":
            self.problem(at, f"sourceBase {binding.get('sourceBase')!r} is not supported: put the .ssv file in "
                             "the package and name it relative to the SSD")
            return None
        with zipfile.ZipFile(self.path) as zf:
            member = posixpath.normpath(source)
            if "://" in source or source.startswith("/") or member.startswith("..") or member not in zf.namelist():
                self.problem(at, f"source {source!r} is not a file in the package")
                return None
            try:
                root = etree.fromstring(zf.read(member))
            except etree.XMLSyntaxError as exc:
                self.problem(at, f"{source}: not well-formed XML: {exc}")
                return None
        from master.scenario.ssp import schema

        checker = schema("ssv")
        if not checker.validate(etree.ElementTree(root)):
            for e in checker.error_log:
                self.problem(at, f"{source} breaks the SSP 1.0 schema: line {e.line}: {e.message}")
            return None
        return root

    def parameter(self, at: str, full_name: str, parameter: etree._Element, components: dict[str, _Component],
                  system_level: bool) -> None:
        if system_level:
            comp_name, _, var_name = full_name.partition(".")
            comp = components.get(comp_name)
            if comp_name in self.failed:
                return
            if comp is None or not var_name:
                self.problem(f"{at}: Parameter {full_name!r}", f"names no component's variable (component.variable; "
                                                               f"components: {', '.join(components) or 'none'})")
                return
        else:
            comp, var_name = next(iter(components.values())), full_name
        where = f"{at}: Parameter {full_name!r}"
        var = comp.variables.get(var_name)
        if var is None:
            self.problem(where, f"{comp.path.name} has no variable {var_name!r} ({_hint(var_name, comp.variables)})")
            return
        value = next(_children(parameter), None)
        kind = etree.QName(value).localname if value is not None else None
        if kind == "Binary" or value is None:
            self.problem(where, f"{kind or 'no'} value: not supported")
            return
        try:
            converted = from_ssv(var, kind, value.get("value"))
        except ValueError as exc:
            self.problem(where, str(exc))
            return
        table = "parameters" if var.causality == "parameter" else "start"
        other = "start" if table == "parameters" else "parameters"
        comp.table.setdefault(table, {})[var_name] = converted
        comp.table.get(other, {}).pop(var_name, None)

    # -- connections ----------------------------------------------------------------------------
    def connections(self, system: etree._Element, components: dict[str, _Component]) -> list[str]:
        result = []
        for connection in system.iterfind("ssd:Connections/ssd:Connection", NS):
            ends = [(connection.get("startElement"), connection.get("startConnector")),
                    (connection.get("endElement"), connection.get("endConnector"))]
            where = "Connection " + " -> ".join(f"{e}.{c}" if e else c for e, c in ends)
            transformation = next((c for c in _children(connection) if etree.QName(c).localname not in _LAYOUT), None)
            if transformation is not None:
                self.problem(where, f"{etree.QName(transformation).localname} is not supported: connect the "
                                    "variables as they are")
                continue
            found = [self.end(where, element, name, components) for element, name in ends]
            if None in found:
                continue
            (kind_a, unit_a), (kind_b, unit_b) = found
            if {kind_a, kind_b} != {"output", "input"}:
                self.problem(where, f"connects a {kind_a} to a {kind_b}: the master connects an output to an input")
                continue
            if unit_a and unit_b and unit_a != unit_b:
                self.problem(where, f"units differ ({unit_a} and {unit_b}): unit conversion is not supported")
                continue
            src, dst = ends if kind_a == "output" else ends[::-1]
            result.append(f"{src[0]}.{src[1]} -> {dst[0]}.{dst[1]}")
        return result

    def end(self, where: str, element: str | None, name: str, components: dict[str, _Component]):
        """(kind, unit) of one end of a connection, or None after saying what is wrong with it."""
        if element is None:
            self.problem(where, f"{name!r} is a connector of the system itself, which is not supported")
            return None
        comp = components.get(element)
        if comp is None and element in self.failed:
            return None
        if comp is None:
            self.problem(where, f"no component {element!r} ({_hint(element, components)})")
            return None
        if name not in comp.connectors:
            in_fmu = "" if name in comp.variables else f"; {comp.path.name} has no variable {name!r} either"
            self.problem(where, f"component {element!r} has no connector {name!r} "
                                f"({_hint(name, comp.connectors)}{in_fmu})")
            return None
        return comp.connectors[name]

    # -- the experiment -------------------------------------------------------------------------
    def experiment(self, root: etree._Element, raw: dict[str, Any], components: dict[str, _Component]) -> None:
        experiment = root.find("ssd:DefaultExperiment", NS)
        if experiment is None:
            return
        time = raw["time"]
        for attr, key in (("startTime", "start"), ("stopTime", "stop")):
            if experiment.get(attr) is not None:
                time[key] = float(experiment.get(attr))  # an xs:double: the schema check passed
        for annotation in experiment.iterfind("ssd:Annotations/ssc:Annotation", NS):
            if annotation.get("type") == ANNOTATION_TYPE:
                self.master_annotation(annotation, raw)

    def master_annotation(self, annotation: etree._Element, raw: dict[str, Any]) -> None:
        where = f"DefaultExperiment: Annotation {ANNOTATION_TYPE!r}"
        for master in _children(annotation):
            if master.tag != f"{{{NS['v2i']}}}Master":
                self.problem(where, f"unknown element {etree.QName(master).localname!r} (expected Master)")
                continue
            for attr, text in master.attrib.items():
                if attr not in _MASTER_ATTRS:
                    self.problem(where, f"Master has an unknown attribute {attr!r} ({_hint(attr, _MASTER_ATTRS)})")
                    continue
                key, cast = _MASTER_ATTRS[attr]
                try:
                    raw["time"][key] = cast(text)
                except ValueError:
                    self.problem(where, f"Master {attr}={text!r} is not a number")
            stop_on, record = [], []
            for child in _children(master):
                tag = etree.QName(child).localname
                if tag == "StopOn" and child.get("condition") is not None:
                    stop_on.append(child.get("condition"))
                elif tag == "Record" and child.get("variable") is not None:
                    record.append(child.get("variable"))
                else:
                    self.problem(where, f"unknown content {etree.tostring(child).decode()!r}")
            if stop_on:
                raw["time"]["stop_on"] = stop_on
            if record:
                raw["record"] = {"variables": record}


class _Component:
    """One FMU component as read so far: its file, model description, connectors and [fmus.NAME] table."""

    def __init__(self, name: str, path: Path, md):
        self.name, self.path, self.md = name, path, md
        self.variables = {v.name: v for v in md.modelVariables}
        self.connectors: dict[str, tuple[str, str | None]] = {}  # name -> (kind, unit of an ssc:Real)
        self.table: dict[str, Any] = {"fmu": str(path)}
