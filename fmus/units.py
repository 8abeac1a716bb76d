"""SI unit table for modelDescription.xml `<UnitDefinitions>`.

FMI 2 tools convert and check units through the exponents of the SI base
units, so every unit a variable uses is declared here once.
"""

# unit name -> exponents of the SI base units (FMI 2 `BaseUnit` attributes)
BASE_UNITS: dict[str, dict[str, int]] = {
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
}


def base_unit_attributes(unit: str) -> dict[str, str]:
    """`BaseUnit` attributes of `unit`; KeyError names units missing from the table."""
    try:
        exponents = BASE_UNITS[unit]
    except KeyError:
        raise KeyError(f"unit {unit!r} is not in fmus.units.BASE_UNITS") from None
    return {k: str(v) for k, v in exponents.items()}
