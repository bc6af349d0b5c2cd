"""The gyro clock (``qkf.redundant_gyros.clock``) against schedules run by hand
(docs/redundant_gyros.md, "Clock")."""

from __future__ import annotations

import numpy as np
import pytest

from qkf.redundant_gyros import clock as gc
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config

CFG = ["scenario.duration_s=160"]
SEEDS = [5_000_020, 5_000_021]


def test_grid_scores_are_the_clocks_run_whole() -> None:
    cfg = load_config("gyro_noise_levels", CFG)
    ep = hs.episode(cfg, SEEDS[0])
    grid = gc.grid_scores(ep)
    assert grid.shape == (len(gc.SWITCH_S), ep.kappas.size, ep.kappas.size)
    for s, a, c in [(0, 0, 10), (2, 7, 3), (5, 4, 9)]:
        clock = gc.Clock(float(ep.kappas[a]), float(ep.kappas[c]), gc.SWITCH_S[s])
        assert grid[s, a, c] == pytest.approx(gc.score(ep, clock), rel=1e-12)
    # never switching is the constant κ_a: the diagonal of the constants
    np.testing.assert_allclose(grid[-1, :, 0], hs.constant_scores(ep), rtol=1e-12)


def test_switch_falls_on_a_period_start() -> None:
    cfg = load_config("gyro_noise_levels", CFG)
    ep = hs.episode(cfg, SEEDS[0])
    kap = gc.Clock(1.0, 2.0, 55.0).kappa(ep)
    first = int(np.argmax(kap == 2.0))
    assert first % ep.period == 0 and first * 0.1 >= 55.0 and (first - ep.period) * 0.1 < 55.0
    assert np.all(kap[:first] == 1.0) and np.all(kap[first:] == 2.0)


def test_tuned_clock_is_the_grid_minimum_and_no_worse_than_a_constant() -> None:
    cfg = load_config("gyro_noise_levels", CFG)
    clock, mean = gc.tune(cfg, SEEDS)
    assert len(gc.SWITCH_S) * 11 * 11 >= 50  # the like-for-like budget
    eps = [hs.episode(cfg, s) for s in SEEDS]
    assert mean == pytest.approx(np.mean([gc.score(e, clock) for e in eps]), rel=1e-12)
    constants = np.mean([hs.constant_scores(e) for e in eps], axis=0)
    assert mean <= constants.min()
