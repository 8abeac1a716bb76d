"""SI unit table for modelDescription.xml `<UnitDefinitions>`.

FMI 2 tools convert and check units through the exponents of the SI base
units, so every unit a variable uses is declared here once.
"""

# unit name -> FMI 2 `BaseUnit` attributes: exponents of the SI base units,
# and `factor`/`offset` for scaled units (value_SI = factor * value + offset).
# Logarithmic units (dB, dBm) have no SI exponents: tools treat them as names.
BASE_UNITS: dict[str, dict[str, float]] = {
    "1": {},
    "m": {"m": 1},
    "m2": {"m": 2},
    "kg": {"kg": 1},
    "kg/m3": {"kg": 1, "m": -3},
    "s": {"s": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "Hz": {"s": -1},
    "GHz": {"s": -1, "factor": 1e9},
    "bit/s": {"s": -1},
    "byte": {},
    "dB": {},
    "dBm": {},
    "dBi": {},
    "ms": {"s": 1, "factor": 0.001},
    "1/m": {"m": -1},
    "1/s": {"s": -1},
    "dB/m": {"m": -1},
}


def base_unit_attributes(unit: str) -> dict[str, str]:
    """`BaseUnit` attributes of `unit`; KeyError names units missing from the table."""
    try:
        exponents = BASE_UNITS[unit]
    except KeyError:
        raise KeyError(f"unit {unit!r} is not in fmus.units.BASE_UNITS") from None
    return {k: repr(v) if isinstance(v, float) else str(v) for k, v in exponents.items()}
