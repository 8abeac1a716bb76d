"""Which lamps of a traffic-light head are lit for a J2735 MovementPhaseState.

The controller FMU's `state_k` outputs carry J2735 MovementPhaseState
values; a head shows them with three lamps (red, yellow, green). Flashing
states are drawn steadily lit: a snapshot or a 10 Hz camera cannot tell a
flash from a steady lamp anyway. No pybullet here, so plots and tests can
use the same colours as the scene.
"""
from __future__ import annotations

LAMPS = ("red", "yellow", "green")  # top to bottom
LIT_RGB = {"red": (1.0, 0.08, 0.05), "yellow": (1.0, 0.78, 0.05), "green": (0.1, 1.0, 0.35)}
DIM_RGB = {"red": (0.22, 0.06, 0.05), "yellow": (0.22, 0.18, 0.05), "green": (0.05, 0.2, 0.09)}
HOUSING_RGB = (0.08, 0.08, 0.08)
POLE_RGB = (0.35, 0.36, 0.38)

# J2735 MovementPhaseState -> lit lamps
_LIT = {
    0: (),                   # unavailable
    1: (),                   # dark
    2: ("red",),             # stop-Then-Proceed (flashing red)
    3: ("red",),             # stop-And-Remain
    4: ("red", "yellow"),    # pre-Movement (red + amber where used)
    5: ("green",),           # permissive-Movement-Allowed
    6: ("green",),           # protected-Movement-Allowed
    7: ("yellow",),          # permissive-clearance
    8: ("yellow",),          # protected-clearance
    9: ("yellow",),          # caution-Conflicting-Traffic (flashing yellow)
}


def lit_lamps(state: int) -> tuple[str, ...]:
    """The lamps lit for MovementPhaseState `state`; unknown values show dark (nothing lit)."""
    return _LIT.get(int(state), ())


def lamp_colours(state: int) -> dict[str, tuple[float, float, float]]:
    """RGB (0..1) of each lamp for `state`: its lit colour if lit, else its dim colour."""
    lit = lit_lamps(state)
    return {lamp: (LIT_RGB if lamp in lit else DIM_RGB)[lamp] for lamp in LAMPS}


def state_name(state: int) -> str:
    """A short word for plots and logs: red, red+yellow, green, yellow, dark."""
    lit = lit_lamps(state)
    return "+".join(lit) if lit else "dark"
