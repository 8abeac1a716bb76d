"""bridges.v2x: the keys and trace-stamp names every process shares, and the stage arithmetic."""
from __future__ import annotations

import math

import pytest

from bridges import v2x


def test_keys():
    assert v2x.tx_key("rsu1") == "v2x/tx/rsu1" and v2x.rx_key("cav") == "v2x/rx/cav"
    assert v2x.trace_key("av") == "trace/av"


def test_stamp_round_trip_is_exact_to_the_nanosecond():
    for t in (0.0, 0.1 + 0.2, 5.93, 3600.123456789):
        assert v2x.stamp_s(v2x.stamp_ns(t)) == pytest.approx(t, abs=1e-9)
    assert v2x.stamp_ns(1.5) == 1_500_000_000
    with pytest.raises(ValueError, match="finite"):
        v2x.stamp_ns(math.nan)


def test_stages_chain_frame_to_command():
    names = [a for a, _ in v2x.STAGES.values()] + [b for _, b in v2x.STAGES.values()]
    assert set(names) <= set(v2x.STAMPS) and len(set(v2x.STAMPS)) == len(v2x.STAMPS)
    # stage1 + stage2 + air + stage3 end where they start: frame -> ... -> can_command
    chain = [v2x.STAGES[s] for s in ("stage1", "stage2", "air", "stage3")]
    assert all(a[1] == b[0] for a, b in zip(chain, chain[1:]))
    stamps = {v2x.FRAME: 0, v2x.DETECT_END: 30_000_000, v2x.SEND: 31_000_000, v2x.AIR_ARRIVAL: 32_500_000,
              v2x.CAN_COMMAND: 35_000_000, v2x.CAN_APPLIED: 40_000_000}
    assert v2x.stage_ms(stamps, "stage1") == 30.0 and v2x.stage_ms(stamps, "stage2") == 1.0
    assert v2x.stage_ms(stamps, "air") == 1.5 and v2x.stage_ms(stamps, "stage3") == 2.5
    assert v2x.stage_ms(stamps, "e2e") == 40.0
    assert v2x.stage_ms({v2x.FRAME: 0}, "stage1") is None
