"""Evaluation tools: score the apps' pieces against the simulator's truth.

Like `benchmarks/` and `tests/`, this package may import everything (the
master's world and scenarios beside the apps' code); nothing imports it but
the `v2i` command, which finds its commands through the `v2i.commands` entry
points (tests/test_boundaries.py keeps master/ and the apps from importing it).

    tracker_sequence.py   detect -> project -> track on a scenario's camera sequence, scored on truth
    cli.py                `v2i eval-tracker`
"""
