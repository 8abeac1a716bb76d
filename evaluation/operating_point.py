"""Which operating point of the RSU app's perception a sweep selects (benchmarks/rsu_app.py --tune).

Kept apart from the benchmark so the rule itself is tested: a default chosen this way is only as
trustworthy as the rule that chose it. Each row is one point's scores over the tuning sequences
(`false_track_frames`, `id_switches`, `min_coverage`, `mean_coverage`, `position_median_m`, `point`).
"""
from __future__ import annotations

KEEP_DEFAULTS_M = 0.01  # a default is not changed for a point less than this much better in median position


def rank(row: dict) -> tuple:
    """What the rule compares first: false track-frames and id switches (fewer), then the coverage of the
    worst-covered vehicle, then the mean coverage (higher). A frame of coverage is a real difference; a
    centimetre of median error over a few hundred samples is not, so errors come only after all of these."""
    return row["false_track_frames"] + row["id_switches"], -row["min_coverage"], -row["mean_coverage"]


def _key(row: dict) -> tuple:
    return (*rank(row), row["position_median_m"])


def order(rows: list[dict]) -> list[dict]:
    """The rows best first: by `rank`, then by median position error."""
    return sorted(rows, key=_key)


def select(rows: list[dict], defaults: dict, keep_defaults_m: float = KEEP_DEFAULTS_M) -> dict:
    """The selected point: the best of `order`, except that the present defaults stay selected when they are
    equal to it on every count and coverage and less than `keep_defaults_m` behind it in median position
    error (changing a default has a cost; a difference below the measurement's resolution does not pay it)."""
    if not rows:
        raise ValueError("no operating points to select from")
    best = min(rows, key=_key)
    for r in rows:
        if (r["point"] == defaults and rank(r) == rank(best)
                and r["position_median_m"] < best["position_median_m"] + keep_defaults_m):
            return r["point"]
    return best["point"]
