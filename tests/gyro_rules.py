"""Checks shared by the tests of the gyro adaptive κ rules (``nis_adaptive``, ``sage_husa``,
``vb_noise``): a rule follows its equations stepped by hand, a rule that never adapts is the
constant κ, and the tuned rule is never worse than the best constant on its tuning episodes."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pytest

from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.methods import GYRO_METHODS


def assert_follows_by_hand(
    seeds: Sequence[int], j: np.ndarray, by_hand: Callable[[int], float]
) -> None:
    """``j`` (one per seed) is ``by_hand(seed)``, the rule stepped with filterpy's UKF epoch by
    epoch, to 1e-6 (the compiled UKF equals filterpy's to rounding, and κ follows it)."""
    np.testing.assert_allclose(j, [by_hand(s) for s in seeds], rtol=1e-6)


def assert_constant_kappa(
    cfg: GyrosConfig, seeds: Sequence[int], j: np.ndarray, kappa: float
) -> None:
    """``j`` (one per seed) is ``J`` of the compiled UKF held at ``kappa`` over each whole
    episode, to 1e-12."""
    for seed, value in zip(seeds, j, strict=True):
        ep = hs.episode(cfg, seed)
        ukf = hs.CompiledUKF(ep)
        x, p = ukf.prior()
        const = ukf.score(ukf.run(x, p, np.full(ep.n_epochs, kappa), 0, ep.n_epochs))
        assert value == pytest.approx(const, rel=1e-12)


def assert_tuning_nests_the_constants(
    cfg: GyrosConfig, tuning: Sequence[hs.Episode], score: float, kappa0: float, method: str
) -> None:
    """A rule tuned on ``tuning`` with mean ``J`` ``score`` and start ``kappa0`` is never worse
    than the best constant κ there, and the registered ``method`` judged on those episodes
    gives the same mean."""
    constant = GYRO_METHODS["constant"](cfg, tuning, tuning)
    assert score <= float(np.mean(constant)) * (1 + 1e-12)
    tuned = GYRO_METHODS[method](cfg, tuning, tuning)  # judged on its tuning episodes
    assert float(np.mean(tuned)) == pytest.approx(score, rel=1e-12)
    assert kappa0 in np.asarray(cfg.environment.actions.values())
