"""SSP 1.0 (System Structure and Parameterization, Modelica Association): the format facts both ways share.

An SSP package is a zip holding `SystemStructure.ssd` (the system: FMU components,
their connectors, parameter bindings, connections, a default experiment) and the
FMUs under `resources/`. `v2i export-ssp` writes one from a scenario
(master.scenario.ssp_export), and `v2i run system.ssp` reads one back into the tables of a
scenario (master.scenario.ssp_import), so the FMI tools that load SSPs (FMPy, OMSimulator,
…) and this master exchange the same system.

Here: the namespaces, the schema check against the standard's XSDs (FMPy ships
them), and the mapping between a variable's value and its `ssv:` element. What
SSP 1.0 has no element for — the master's step, mode and ordering, an
instance's step multiple, the recorded variables — travels in an annotation of
our own type (ANNOTATION_TYPE), which other tools ignore as the standard says.
"""
from __future__ import annotations

import math
from functools import lru_cache
from importlib.resources import files
from typing import Any

from lxml import etree

SSD_NAME = "SystemStructure.ssd"  # the default system structure of a package
RESOURCES = "resources/"  # where the FMUs lie inside the package
FMU_TYPE = "application/x-fmu-sharedlibrary"  # Component type of an FMU (the schema's default)
PARAMETER_SET_TYPE = "application/x-ssp-parameter-set"  # ParameterBinding type of ssv files (the default)

SSD_NS = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC_NS = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
SSM_NS = "http://ssp-standard.org/SSP1/SystemStructureParameterMapping"
SSB_NS = "http://ssp-standard.org/SSP1/SystemStructureSignalDictionary"
V2I_NS = "urn:v2i-cosim:ssp:1"  # the content of our annotations
NS = {"ssd": SSD_NS, "ssc": SSC_NS, "ssv": SSV_NS, "ssm": SSM_NS, "ssb": SSB_NS, "v2i": V2I_NS}

# Annotation types are reverse-domain names chosen by whoever defines them (ssc:TAnnotations): this one is the
# project's own name in that form. It carries the master's time settings and record list (in DefaultExperiment)
# and an instance's step multiple (in its Component).
ANNOTATION_TYPE = "org.v2i-cosim.master"

_SCHEMA_FILES = {"ssd": "SystemStructureDescription.xsd", "ssv": "SystemStructureParameterValues.xsd"}


class SspError(ValueError):
    """A scenario that cannot be written as an SSP, or a package that breaks the SSP 1.0 schema."""


def q(prefix: str, name: str) -> str:
    """The qualified (Clark) name of an element, e.g. q("ssd", "Component")."""
    return f"{{{NS[prefix]}}}{name}"


@lru_cache(maxsize=None)
def schema(kind: str) -> etree.XMLSchema:
    """The SSP 1.0 XML schema of a file kind ("ssd", "ssv"), as FMPy ships the standard's XSDs."""
    path = files("fmpy.ssp") / "schema" / _SCHEMA_FILES[kind]
    if not path.is_file():
        raise SspError(f"the SSP 1.0 schema {_SCHEMA_FILES[kind]} is not in the installed fmpy ({path})")
    return etree.XMLSchema(etree.parse(str(path)))


def schema_problems(root: etree._Element) -> list[str]:
    """Every breach of the SSP 1.0 schema in an SSD, inline parameter sets included.

    The SSD schema takes the content of ParameterValues laxly (an XSD 1.0 limit, noted in the
    schema itself), so each inline ssv:ParameterSet is checked against its own schema here."""
    problems = []
    ssd_schema = schema("ssd")
    if not ssd_schema.validate(root):
        problems += [f"line {e.line}: {e.message}" for e in ssd_schema.error_log]
    ssv_schema = schema("ssv")
    for pset in root.iterfind(".//ssd:ParameterValues/ssv:ParameterSet", NS):
        if not ssv_schema.validate(etree.ElementTree(pset)):
            problems += [f"ParameterSet {pset.get('name')!r}: {e.message}" for e in ssv_schema.error_log]
    return problems


# -- values ----------------------------------------------------------------------------------------------
_CONNECTOR_TYPES = {"real": "Real", "integer": "Integer", "boolean": "Boolean", "string": "String"}


def connector_type(var) -> str | None:
    """The ssc type element of a connector for this FMU variable (None: let the FMU's variable say it).

    An Enumeration would need its enumeration declared in the SSD; the standard lets a connector
    leave its type out, so it does."""
    from master.fmi.variables import family

    return None if var.type == "Enumeration" else _CONNECTOR_TYPES.get(family(var.type))


def format_double(value: float) -> str:
    """xs:double text: the shortest text that reads back as the same float (INF, -INF, NaN spelt as XSD does)."""
    value = float(value)
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "INF" if value > 0 else "-INF"
    return repr(value)


def to_ssv(var, value: Any) -> tuple[str, str]:
    """(ssv element name, value attribute) of a scenario value (as TOML gives it) for FMU variable `var`."""
    from master.fmi.variables import family

    fam = family(var.type)
    if var.type == "Enumeration":
        items = {item.value: item.name for item in getattr(var.declaredType, "items", None) or []}
        name = items.get(str(value))
        if name is None:
            raise SspError(f"{var.name}: {value!r} is none of the values of its enumeration "
                           f"({', '.join(f'{v}={n}' for v, n in items.items()) or 'no items declared'})")
        return "Enumeration", name
    if fam == "real":
        return "Real", format_double(value)
    if fam == "integer":
        return "Integer", str(int(value))
    if fam == "boolean":
        return "Boolean", "true" if value else "false"
    if fam == "string":
        return "String", str(value)
    raise SspError(f"{var.name}: variables of type {var.type} have no SSP parameter value")


_XS_BOOLEAN = {"true": True, "1": True, "false": False, "0": False}
_ACCEPTS = {"real": ("Real", "Integer"), "integer": ("Integer",), "boolean": ("Boolean",), "string": ("String",)}


def from_ssv(var, kind: str, text: str) -> Any:
    """The scenario value of an ssv value element `kind` with attribute `text`, for FMU variable `var`.

    Raises ValueError with the reason when the element does not fit the variable's type."""
    from master.fmi.variables import family

    fam = family(var.type)
    if var.type == "Enumeration" and kind == "Enumeration":
        items = {item.name: item.value for item in getattr(var.declaredType, "items", None) or []}
        if text not in items:
            raise ValueError(f"{text!r} is no item of the variable's enumeration ({', '.join(items) or 'none'})")
        return int(items[text])
    if kind not in _ACCEPTS.get(fam, ()):
        raise ValueError(f"an ssv:{kind} value does not fit {var.name!r}, a {var.type} variable")
    try:
        if kind == "Real":
            return float(text)
        if kind == "Integer":
            return int(text.strip())
        if kind == "Boolean":
            return _XS_BOOLEAN[text.strip()]
    except (ValueError, KeyError):
        raise ValueError(f"{text!r} is not an xs:{kind.lower() if kind != 'Real' else 'double'}") from None
    return text
