"""Type families of FMI 2 / FMI 3 variables, for connection and value checks."""
from __future__ import annotations

# FMI type name -> family used for connection compatibility and value checks
_FAMILIES = {
    "Real": "real", "Float64": "real", "Float32": "real",
    "Integer": "integer", "Enumeration": "integer",
    "Int8": "integer", "Int16": "integer", "Int32": "integer", "Int64": "integer",
    "UInt8": "integer", "UInt16": "integer", "UInt32": "integer", "UInt64": "integer",
    "Boolean": "boolean", "String": "string",
}


# Families the master can set, get, connect and record (not Binary, Clock).
SUPPORTED_FAMILIES = ("real", "integer", "boolean", "string")


def family(fmi_type: str) -> str:
    return _FAMILIES.get(fmi_type, fmi_type.lower())


def unsupported_reason(var) -> str | None:
    """Why the master cannot exchange this variable, or None when it can."""
    if getattr(var, "dimensions", None):
        return f"{var.name!r} is an array variable (FMI 3 dimensions); arrays are not supported yet"
    if family(var.type) not in SUPPORTED_FAMILIES:
        return f"{var.name!r} is of type {var.type}, which the master cannot exchange"
    return None


def check_value(fmi_type: str, value) -> str | None:
    """None when `value` (from TOML) fits a variable of `fmi_type`, else the reason."""
    fam = family(fmi_type)
    if fam == "real":
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif fam == "integer":
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif fam == "boolean":
        ok = isinstance(value, bool)
    elif fam == "string":
        ok = isinstance(value, str)
    else:
        return f"variables of type {fmi_type} are not supported"
    if ok:
        return None
    return f"expected a {fam} value for a {fmi_type} variable, got {type(value).__name__} {value!r}"
