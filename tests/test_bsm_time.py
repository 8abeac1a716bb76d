"""A BSM's measurement time survives the trip RSU -> secMark -> AV exactly, whatever the run's epoch.

The epoch is the wall clock when a run began, so its phase within the millisecond differs from run to
run; a lockstep run must repeat bit for bit all the same (the AV app predicts each BSM from its
measurement time: 1 ms off is 8 mm at 30 km/h, and enough to change a decision later in the run).
"""
from __future__ import annotations

import numpy as np

from av_app.obu import measurement_time
from rsu_app.bsm_stage import sec_mark_ms


def test_the_measurement_time_does_not_depend_on_the_epochs_phase():
    rng = np.random.default_rng(7)
    epochs = 1_795_000_000 + rng.integers(0, 10_000_000, 200) + rng.random(200)  # any sub-ms phase
    slots = np.round(rng.uniform(0.0, 120.0, 200), 3)  # BSM slots on the simulation's millisecond grid
    for epoch in epochs:
        for t in slots:
            t = float(t)
            got = measurement_time(sec_mark_ms(t, float(epoch)), t + 0.0123, float(epoch), None)
            assert got == round(t, 3), (epoch, t, got)


def test_sec_mark_counts_milliseconds_within_the_minute():
    assert sec_mark_ms(0.0, 1_800_000_000.0) == 0  # 1 800 000 000 s is a whole minute
    assert sec_mark_ms(0.4535, 1_800_000_000.0) == 453
    assert sec_mark_ms(59.999, 1_800_000_000.0) == 59999
    assert sec_mark_ms(60.0, 1_800_000_000.0) == 0
    assert sec_mark_ms(0.0, 1_800_000_000.0004) == 0 and sec_mark_ms(0.0, 1_800_000_000.0006) == 1
