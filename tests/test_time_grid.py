"""qkf.core.time_grid: windows of a sorted time grid found by bisection are the epochs the
direct masks pick (``start <= t < end``; outside every window), bounds on the grid and beside
it included: what the transfer-alignment manoeuvres, ADS gaps and walk segments and the
fusion's data and star-camera gaps use."""

from __future__ import annotations

import numpy as np

from qkf.core.time_grid import epochs_in, outside_windows


def _bounds(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Window bounds on grid points, between them, beyond both ends, and a hair off a point."""
    n = t.size
    bounds = np.concatenate([t[rng.integers(0, n, 40)], rng.uniform(-5, 1.1 * t[-1] + 5, 40)])
    return np.concatenate([bounds, bounds - 1e-9, bounds + 1e-9, np.nextafter(bounds, 0)])


def test_epoch_windows_are_the_mask_over_every_epoch() -> None:
    rng = np.random.default_rng(3)
    for dt in (0.1, 0.25, 1.0, 1.7):
        t = np.arange(400) * dt
        for start, end in rng.choice(_bounds(rng, t), (300, 2)):
            mask = (t >= start) & (t < end)
            np.testing.assert_array_equal(
                np.flatnonzero(mask), np.arange(400)[epochs_in(t, start, end)]
            )


def test_outside_windows_is_the_mask_outside_every_window() -> None:
    rng = np.random.default_rng(5)
    for dt in (0.2, 1.0, 3.3):
        t = np.arange(300) * dt
        for count in (0, 1, 4, 12):
            windows = [tuple(w) for w in rng.choice(_bounds(rng, t), (count, 2))]
            keep = np.ones(t.size, dtype=bool)
            for lo, hi in windows:
                keep &= ~((t >= lo) & (t < hi))
            np.testing.assert_array_equal(outside_windows(t, windows), keep)
