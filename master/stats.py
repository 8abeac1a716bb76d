"""Distribution summaries for timing data (medians and tails, not just means)."""
from __future__ import annotations

from typing import Iterable, Sequence


def percentiles(samples: Sequence[float], points: Iterable[int] = (50, 99)) -> dict[str, float | int | None]:
    """{'n', 'mean', 'pXX'..., 'max'} of `samples`; None values when there are none."""
    import numpy as np

    data = np.asarray(samples, dtype=float)
    out: dict[str, float | int | None] = {"n": int(data.size)}
    if data.size == 0:
        out.update({"mean": None, **{f"p{p}": None for p in points}, "max": None})
        return out
    out["mean"] = float(data.mean())
    for p in points:
        out[f"p{p}"] = float(np.percentile(data, p))
    out["max"] = float(data.max())
    return out
