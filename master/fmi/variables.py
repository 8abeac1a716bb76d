"""Type families, value ranges and array shapes of FMI 2 / FMI 3 variables.

The checks here stand between a value (from the scenario, an input file or a
connection) and the ctypes call that hands it to the FMU: ctypes converts a
Python int into an Int8 by wrapping it (300 becomes 44, -1 into a UInt8 255)
and a float into a Float32 by overflowing it (1e300 becomes inf), silently.
So every value is held against its variable's type range and the `min`/`max`
its model description declares before it is set.
"""
from __future__ import annotations

import math
from typing import Any

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

FLOAT32_MAX = 3.4028234663852886e38  # the largest finite IEEE 754 single
_INT_BITS = {"Int8": (True, 8), "Int16": (True, 16), "Int32": (True, 32), "Int64": (True, 64),
             "UInt8": (False, 8), "UInt16": (False, 16), "UInt32": (False, 32), "UInt64": (False, 64),
             "Integer": (True, 32)}  # FMI 2's Integer is a C int (fmi2Integer)


def family(fmi_type: str) -> str:
    return _FAMILIES.get(fmi_type, fmi_type.lower())


def type_range(fmi_type: str, fmi3: bool = True) -> tuple[float, float] | None:
    """The values a variable of `fmi_type` can hold, or None when any value of its family fits.

    Integers: the C type's range (an Enumeration is an fmi2Integer in FMI 2, an Int64 in FMI 3);
    Float32: the finite single range (an infinity given as such stays one, it does not overflow).
    """
    if fmi_type == "Enumeration":
        fmi_type = "Int64" if fmi3 else "Integer"
    if fmi_type in _INT_BITS:
        signed, bits = _INT_BITS[fmi_type]
        return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if fmi_type == "Float32":
        return (-FLOAT32_MAX, FLOAT32_MAX)
    return None


def declared_bound(var, attr: str) -> tuple[float | None, str]:
    """The variable's `min` or `max` (its own, else its declared type's) and where it is declared;
    (None, "") when there is none."""
    text, where = getattr(var, attr, None), ""
    declared = getattr(var, "declaredType", None)
    if text is None and declared is not None:
        text, where = getattr(declared, attr, None), f" (declared type {declared.name})"
    if text is None:
        return None, ""
    try:
        return (int(text) if family(var.type) == "integer" else float(text)), where
    except ValueError:
        return float(text), where  # "1e3" on an Integer: still a bound


def shape(var) -> tuple[int, ...]:
    """An FMI 3 array's fixed shape (fmpy resolves it from the model description); () for a scalar."""
    if not getattr(var, "dimensions", None):
        return ()
    return tuple(getattr(var, "shape", None) or ())


def size(var) -> int:
    """How many values the variable holds: 1 for a scalar, the product of an array's dimensions."""
    return math.prod(shape(var))


def element_names(name: str, dims: tuple[int, ...]) -> list[str]:
    """`name` for a scalar; `name[1]`, `name[2]`, ... for an array (row-major, `name[i,j]` for 2-D).

    1-based, as in FMI's structured naming convention, so an FMI 3 array and the
    scalarised variables an FMI 2 export of the same model has give the same columns.
    """
    if not dims:
        return [name]
    indices = [()]
    for n in dims:
        indices = [(*i, k) for i in indices for k in range(1, n + 1)]
    return [f"{name}[{','.join(map(str, i))}]" for i in indices]


def describe_type(var) -> str:
    """`Float64`, or `Float64[3]` for an array: how messages and `v2i info` name a variable's type."""
    dims = shape(var)
    return f"{var.type}[{','.join(map(str, dims))}]" if dims else var.type


def unsupported_reason(var) -> str | None:
    """Why the master cannot exchange this variable, or None when it can."""
    if getattr(var, "dimensions", None):
        dims = getattr(var, "shape", None)
        if not dims or len(dims) != len(var.dimensions) or not all(isinstance(d, int) and d > 0 for d in dims):
            return f"{var.name!r} is an array variable (FMI 3 dimensions) without a fixed size; not supported"
    if family(var.type) not in SUPPORTED_FAMILIES:
        return f"{var.name!r} is of type {var.type}, which the master cannot exchange"
    return None


def check_value(fmi_type: str, value, fmi3: bool = True) -> str | None:
    """None when `value` (from TOML) is of the kind and within the range of a `fmi_type` variable, else why."""
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
    if not ok:
        return (f"expected {_article(fam)} {fam} value for {_article(fmi_type)} {fmi_type} variable, "
                f"got {type(value).__name__} {value!r}")
    return outside_type_range(fmi_type, value, fmi3)


def outside_type_range(fmi_type: str, value, fmi3: bool = True) -> str | None:
    """Why `value` does not fit a `fmi_type` variable (it would wrap or overflow), or None."""
    bounds = type_range(fmi_type, fmi3)
    if bounds is None or not isinstance(value, (int, float)) or isinstance(value, bool):
        return None
    low, high = bounds
    if fmi_type == "Float32":
        if math.isfinite(value) and abs(value) > high:
            return f"{value!r} is outside the range of a Float32 (|value| <= {high:.8g}); it would become inf"
        return None
    if not low <= value <= high:
        name = fmi_type if fmi_type != "Enumeration" else f"Enumeration ({'Int64' if fmi3 else 'fmi2Integer'})"
        return f"{value!r} is outside the range of {_article(name)} {name} [{low}, {high}]; it would wrap around"
    return None


def _article(word: str) -> str:
    return "an" if word[:1] in "aeiouAEIO" else "a"  # "a UInt8": you-int


def outside_declared_bounds(var, value) -> str | None:
    """Why `value` breaks the variable's declared `min`/`max`, or None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    low, where = declared_bound(var, "min")
    if low is not None and value < low:
        return f"{value!r} is below the declared min {low:g} of {var.name!r}{where}"
    high, where = declared_bound(var, "max")
    if high is not None and value > high:
        return f"{value!r} is above the declared max {high:g} of {var.name!r}{where}"
    return None


def check_scalar(var, value, fmi3: bool = True) -> str | None:
    """A single value for `var` (or one element of an array): kind, type range, declared min/max."""
    return check_value(var.type, value, fmi3) or outside_declared_bounds(var, value)


def check_setting(var, value, fmi3: bool = True) -> str | None:
    """None when `value` (from TOML) may be set on `var`, else the reason.

    A scalar takes one value; an array a list of its size (nested lists for
    more dimensions, row-major), every element checked like a scalar.
    """
    dims = shape(var)
    if not dims:
        return check_scalar(var, value, fmi3)
    flat = flatten(value, dims)
    if flat is None:
        return (f"{var.name!r} is a {describe_type(var)} array: expected a list of {size(var)} values"
                + (" (nested row by row)" if len(dims) > 1 else "") + f", got {value!r}")
    for element, item in zip(element_names(var.name, dims), flat):
        reason = check_scalar(var, item, fmi3)
        if reason:
            return f"{element}: {reason}"
    return None


def flatten(value: Any, dims: tuple[int, ...]) -> list | None:
    """The elements of a (nested) list of shape `dims` in row-major order; None when the shape differs.

    A flat list of the full size is accepted for any shape, as FMI 3 itself passes arrays flat.
    """
    if not isinstance(value, list):
        return None
    if len(dims) > 1 and len(value) == math.prod(dims) and not any(isinstance(v, list) for v in value):
        return list(value)
    if len(value) != dims[0]:
        return None
    if len(dims) == 1:
        return None if any(isinstance(v, list) for v in value) else list(value)
    out = []
    for row in value:
        part = flatten(row, dims[1:])
        if part is None:
            return None
        out += part
    return out
