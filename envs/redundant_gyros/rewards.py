r"""Rewards of the redundant-gyro environments: a registry (docs/redundant_gyros.md,
"Environment").

A reward turns one decision period of a batch of calibration episodes (a :class:`GyroPeriod`,
N rows) into N numbers; a non-finite one is replaced by the divergence reward. Built in:
``likelihood`` (default, no truth) ``(ℓ_agent − ℓ_nominal) / (steps Δt)`` with
``ℓ = −½ Σ (ν²/S + log S)`` and the nominal filter a κ = 1 copy run from the same state over
the period; ``oracle`` (truth) minus the period's mean of ``‖(x̂ − x) / σ₀‖``; ``mean_square``
(truth) minus the period's mean of ``‖(x̂ − x) / σ₀‖² / 4``, the hindsight's ``J`` per epoch;
``nees`` (truth)
minus ``|mean NEES / 4 − 1|``. Installed packages can add rewards through the entry-point group
``qkf.gyro_rewards``: a :class:`GyroReward` whose function maps a :class:`GyroPeriod` to an
(N,) array, and that says whether it reads the truth, the κ = 1 copy (``uses_nominal``: the
copy runs only then, or for an observation that reads it) and the covariances (``uses_cov``:
only then are they kept, (N, P, 4, 4) per period).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qkf.core.registry import Registry
from qkf.core.stats import nees


@dataclass(frozen=True)
class GyroPeriod:
    """One decision period of N episodes (internal units). ``P`` is the period's epochs; an
    episode's epochs past its ``steps`` (the last, shorter period) and from a failure on are
    NaN."""

    loglik_gain: np.ndarray  # (N,) ℓ_agent − ℓ_nominal over the period (NaN without the copy)
    errors: np.ndarray  # (N, P, 4) x̂ − x
    cov: np.ndarray | None  # (N, P, 4, 4), kept only for a reward with uses_cov
    prior_sd: np.ndarray  # (4,)
    steps: np.ndarray  # (N,) epochs of the period
    dt: np.ndarray  # (N,) step, s
    normalised_error: np.ndarray  # (N,) the period's mean of ‖(x̂ − x) / σ₀‖
    normalised_sq_error: np.ndarray  # (N,) the period's mean of ‖(x̂ − x) / σ₀‖² / 4


@dataclass(frozen=True)
class GyroReward:
    """A reward function of one period of N episodes, and what it reads."""

    fn: Callable[[GyroPeriod], np.ndarray]
    description: str
    uses_truth: bool = False
    uses_nominal: bool = False
    uses_cov: bool = False


GYRO_REWARDS: Registry[GyroReward] = Registry("gyro reward", group="qkf.gyro_rewards")
"""Rewards of the redundant-gyro environments by name."""


def period_mean(values: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Mean over each row's ``steps`` epochs of ``values`` (N, P) (NaN-padded)."""
    return np.nansum(values, axis=1) / steps


def likelihood_reward(o: GyroPeriod) -> np.ndarray:
    """``(ℓ_agent − ℓ_nominal) / (steps Δt)``, per second."""
    return o.loglik_gain / (o.steps * o.dt)


def oracle_reward(o: GyroPeriod) -> np.ndarray:
    """Minus the period's mean of ``‖(x̂ − x) / σ₀‖``."""
    return -o.normalised_error


def mean_square_reward(o: GyroPeriod) -> np.ndarray:
    """Minus the period's mean of ``‖(x̂ − x) / σ₀‖² / 4``: the hindsight's ``J`` per epoch."""
    return -o.normalised_sq_error


def nees_reward(o: GyroPeriod) -> np.ndarray:
    """Minus ``|mean NEES / 4 − 1|`` over the period."""
    assert o.cov is not None  # registered with uses_cov
    return -np.abs(period_mean(nees(o.errors, o.cov), o.steps) / 4.0 - 1.0)


GYRO_REWARDS.register(
    "likelihood",
    GyroReward(likelihood_reward, "innovation log-likelihood gain over κ = 1", uses_nominal=True),
)
GYRO_REWARDS.register(
    "oracle", GyroReward(oracle_reward, "minus the error over the prior sd", uses_truth=True)
)
GYRO_REWARDS.register(
    "mean_square",
    GyroReward(
        mean_square_reward,
        "minus the mean square error over the prior sd (the judged J)",
        uses_truth=True,
    ),
)
GYRO_REWARDS.register(
    "nees",
    GyroReward(nees_reward, "minus |NEES/4 − 1|", uses_truth=True, uses_cov=True),
)
