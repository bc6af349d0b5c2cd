"""Windows of a sorted time grid: the epochs of ``[start, end)`` as a slice, found by bisection
(two ``searchsorted`` calls) instead of a mask over every epoch per window, which costs
O(epochs × windows) on long runs with many manoeuvres or gaps (docs/performance.md).
"""

from __future__ import annotations

import numpy as np


def epochs_in(t: np.ndarray, start: float, end: float) -> slice:
    """The slice of the sorted times ``t`` (s) with ``start <= t < end``: the same epochs as the
    mask ``(t >= start) & (t < end)``."""
    return slice(int(np.searchsorted(t, start, "left")), int(np.searchsorted(t, end, "left")))


def outside_windows(t: np.ndarray, windows: list[tuple[float, float]]) -> np.ndarray:
    """``True`` at the epochs of the sorted times ``t`` (s) outside every ``[start, end)`` of
    ``windows``."""
    keep = np.ones(t.shape, dtype=bool)
    for start, end in windows:
        keep[epochs_in(t, start, end)] = False
    return keep


__all__ = ["epochs_in", "outside_windows"]
