"""The stepping loop and what it owns: one run from start values to the run folder.

`cosim` is the loop (fixed communication steps, hooks around each), `algorithm` the exchange and
step order of the FMUs due at a point, `initialization` the consistent start values, `pacing` and
`interrupts` wall-clock pacing and clean ends, `recorder` and `run_records` the run folder, `metrics`,
`collision`, `verdict` and `summary` what the run measured and how it is told. The loop reaches the
outside through `master.links` and the pybullet world (`master.world`), both as hooks; it never
imports sweeps, the report or the CLI (tests/test_boundaries.py).
"""
