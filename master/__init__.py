"""The co-simulation master: scenario files, the stepping loop, its links to the outside, run folders, the `v2i` CLI.

Its rooms, in the order they build on each other: `fmi` (one FMU over fmpy), `scenario` (reading and
checking scenario files), `world` (the pybullet world), `links` (apps, serial, CAN, the V2X air,
sensor streams), `run` (the stepping loop and the run folder), `report` and `sweep` (what is made of
finished runs), and `cli` on top. Beside them, flat, the vocabulary every room shares: `errors`,
`hooks` (the one protocol of everything acting around a step), `events` (the run's event log) and
`stats`. tests/test_boundaries.py keeps the direction of the arrows between them.
"""

__version__ = "0.1.0"
