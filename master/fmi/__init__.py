"""The FMI layer: one running FMU over fmpy, the FMI 2 / FMI 3 type system, and `v2i info`.

`runtime` instantiates and steps an FMU (co-simulation, FMI 2 or 3), `variables` knows type
families, value ranges and array shapes, `info` prints an FMU's interface. It knows nothing of
scenarios, the stepping loop or the links: everything else in the master builds on it, it imports
only `master.errors` (tests/test_boundaries.py).
"""
