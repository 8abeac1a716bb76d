"""A scenario's FMU system as an SSP 1.0 package: `v2i export-ssp SCENARIO.toml -o system.ssp`.

What the package holds:

* each instance as a Component (`resources/<fmu file>`, implementation CoSimulation), its
  parameters and start values as one inline parameter set (SSP applies bindings to parameters
  and to start values of inputs alike, before initialization);
* a Connector for every variable a connection, the record list or a parameter value names, of the
  kind its causality gives — except inputs no connection drives: a start value needs no connector,
  and FMPy 0.3.32 wires an unconnected input connector to whatever it found last;
* the connections (start = the output, end = the input), the DefaultExperiment's start and stop;
* in annotations of type master.scenario.ssp.ANNOTATION_TYPE: the step, mode, ordering, rtf, overrun, the
  `stop_on` conditions and the record list (DefaultExperiment), an instance's step multiple
  (Component). SSP 1.0 has no element for them; tools other than this master ignore them.

The scenario's sections (world, bridge/participants, v2x, can, serial, pki, events), an instance's
input file and a camera record have no SSP counterpart: they are left out and named in the returned
warnings. FMI 3 array variables have no SSP 1.0 form either: a scenario that connects, records or
sets one is refused (SspError). The package is
the same bytes for the same scenario (no timestamps), and checked against the SSP 1.0 schema
before it is written.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path

from lxml import etree

from master.scenario.conditions import COLLISION
from master.scenario.loader import Scenario
from master.scenario.sections import section_keys
from master.scenario.ssp import (ANNOTATION_TYPE, FMU_TYPE, NS, RESOURCES, SSD_NAME, SspError, connector_type,
                        format_double, q, schema_problems, to_ssv)

_KIND_OF_CAUSALITY = {"input": "input", "output": "output", "parameter": "parameter",
                      "calculatedParameter": "calculatedParameter"}  # local, independent: no connector
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # every entry's date: the same scenario gives the same bytes


def left_out(scenario: Scenario) -> list[str]:
    """What of the scenario an SSP cannot carry: its sections, a camera record, a collision stop."""
    out = [f"[[{key}]]" if isinstance(scenario.raw[key], list) else f"[{key}]"
           for key in section_keys() if key in scenario.raw]
    out += [f"fmus.{name}.input" for name, inst in scenario.instances.items()  # a CSV driving inputs
            if getattr(inst, "input", None) is not None]
    if scenario.record_camera:
        out.append("record.camera")
    if COLLISION in scenario.time.stop_on:
        out.append('time.stop_on "collision"')
    return out


def export_ssp(scenario: Scenario, out: str | os.PathLike) -> list[str]:
    """Write the scenario's system as the SSP package `out`; returns the warnings (what was left out).

    Raises SspError when a value has no SSP form or the SSD breaks the schema (a bug of ours)."""
    out = Path(out)
    sources = fmu_sources(scenario)
    root = system_structure(scenario, sources)
    problems = schema_problems(root)
    if problems:
        raise SspError("the SSD written breaks the SSP 1.0 schema:\n  " + "\n  ".join(problems))
    ssd = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    write_package(out, ssd, sources)
    dropped = left_out(scenario)
    return [f"left out of {out.name} (SSP 1.0 has no place for them): {', '.join(dropped)}"] if dropped else []


def fmu_sources(scenario: Scenario) -> dict[Path, str]:
    """FMU file -> its place in the package; instances of one FMU share it, two files of one name do not."""
    sources: dict[Path, str] = {}
    for inst in scenario.instances.values():
        if inst.path in sources:
            continue
        stem, n = inst.path.stem, 1
        name = f"{RESOURCES}{inst.path.name}"
        while name in sources.values():
            n += 1
            name = f"{RESOURCES}{stem}-{n}.fmu"
        sources[inst.path] = name
    return sources


def write_package(out: Path, ssd: bytes, sources: dict[Path, str]) -> None:
    """The zip, written beside `out` and moved over it, so a failed export leaves no half package."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.partial")
    try:
        with zipfile.ZipFile(tmp, "w") as zf:
            zf.writestr(zipfile.ZipInfo(SSD_NAME, _ZIP_TIME), ssd, compress_type=zipfile.ZIP_DEFLATED)
            for path, name in sources.items():  # FMUs are zips already: stored as they are
                zf.writestr(zipfile.ZipInfo(name, _ZIP_TIME), path.read_bytes(), compress_type=zipfile.ZIP_STORED)
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)


# -- the SSD ------------------------------------------------------------------------------------------------
def _sub(parent: etree._Element, prefix: str, tag: str, **attrs) -> etree._Element:
    return etree.SubElement(parent, q(prefix, tag), {k: str(v) for k, v in attrs.items()})


def _annotation(parent: etree._Element, tag: str, **attrs) -> etree._Element:
    """`<ssd:Annotations><ssc:Annotation type=ANNOTATION_TYPE><v2i:TAG .../>`: our element inside."""
    annotations = _sub(parent, "ssd", "Annotations")
    annotation = _sub(annotations, "ssc", "Annotation", type=ANNOTATION_TYPE)
    return _sub(annotation, "v2i", tag, **attrs)


def system_structure(scenario: Scenario, sources: dict[Path, str]) -> etree._Element:
    """The SystemStructureDescription element of the scenario's system."""
    from master import __version__

    root = etree.Element(q("ssd", "SystemStructureDescription"),
                         {"version": "1.0", "name": scenario.name, "generationTool": f"v2i-cosim {__version__}"},
                         nsmap={k: NS[k] for k in ("ssd", "ssc", "ssv", "v2i")})
    if scenario.description:
        root.set("description", scenario.description)
    system = _sub(root, "ssd", "System", name=scenario.name)
    elements = _sub(system, "ssd", "Elements")
    for inst in scenario.instances.values():
        component(elements, scenario, inst, sources[inst.path])
    if scenario.connections:
        connections = _sub(system, "ssd", "Connections")
        for c in scenario.connections:
            _sub(connections, "ssd", "Connection", startElement=c.src, startConnector=c.src_var,
                 endElement=c.dst, endConnector=c.dst_var)
    default_experiment(root, scenario)
    return root


def connector_names(scenario: Scenario, name: str) -> set[str]:
    """The variables of instance `name` that get a connector (see the module's docstring)."""
    inst = scenario.instances[name]
    named = {c.src_var for c in scenario.connections if c.src == name}
    named |= {c.dst_var for c in scenario.connections if c.dst == name}
    named |= set(inst.parameters)
    connected_inputs = {c.dst_var for c in scenario.connections if c.dst == name}
    for inst_name, var_name in scenario.record:
        var = inst.variables[var_name] if inst_name == name else None
        if var is not None and (var.causality != "input" or var_name in connected_inputs):
            named.add(var_name)
    return {n for n in named if inst.variables[n].causality in _KIND_OF_CAUSALITY}


def component(elements: etree._Element, scenario: Scenario, inst, source: str) -> None:
    comp = _sub(elements, "ssd", "Component", name=inst.name, type=FMU_TYPE, source=source,
                implementation="CoSimulation")
    names = connector_names(scenario, inst.name)
    values = {**inst.parameters, **inst.start}
    arrays = sorted(n for n in names | set(values) if getattr(inst.variables[n], "dimensions", None))
    if arrays:
        raise SspError(f"{inst.name}: {', '.join(arrays)}: FMI 3 array variables have no SSP 1.0 connector or "
                       "parameter value")
    if names:
        connectors = _sub(comp, "ssd", "Connectors")
        for var in inst.model_description.modelVariables:  # in the FMU's order
            if var.name not in names:
                continue
            connector = _sub(connectors, "ssd", "Connector", name=var.name, kind=_KIND_OF_CAUSALITY[var.causality])
            kind = connector_type(var)
            if kind is not None:
                _sub(connector, "ssc", kind)
    if values:
        bindings = _sub(comp, "ssd", "ParameterBindings")
        binding = _sub(bindings, "ssd", "ParameterBinding")
        pvalues = _sub(binding, "ssd", "ParameterValues")
        pset = _sub(pvalues, "ssv", "ParameterSet", version="1.0", name=inst.name)
        parameters = _sub(pset, "ssv", "Parameters")
        for var_name, value in values.items():
            kind, text = to_ssv(inst.variables[var_name], value)
            _sub(_sub(parameters, "ssv", "Parameter", name=var_name), "ssv", kind, value=text)
    if inst.step_multiple != 1:
        _annotation(comp, "Instance", stepMultiple=inst.step_multiple)


def default_experiment(root: etree._Element, scenario: Scenario) -> None:
    t = scenario.time
    experiment = _sub(root, "ssd", "DefaultExperiment", startTime=format_double(t.start),
                      stopTime=format_double(t.stop))
    master = _annotation(experiment, "Master", step=format_double(t.step), mode=t.mode, ordering=t.ordering,
                         rtf=format_double(t.rtf), overrun=t.overrun)
    for condition in t.stop_on:
        if condition != COLLISION:
            _sub(master, "v2i", "StopOn", condition=condition)
    for inst_name, var_name in scenario.record:
        _sub(master, "v2i", "Record", variable=f"{inst_name}.{var_name}")
