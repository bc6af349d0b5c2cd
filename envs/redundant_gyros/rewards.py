r"""Rewards of ``qkf/RedundantGyroCalibration-v0``: a registry (docs/redundant_gyros.md,
"Environment").

A reward turns one decision period of the calibration UKF (a :class:`GyroPeriod`) into a
number; a non-finite one is replaced by the divergence reward. Built in: ``likelihood``
(default, no truth) ``(ℓ_agent − ℓ_nominal) / (steps Δt)`` with ``ℓ = −½ Σ (ν²/S + log S)``
and the nominal filter a κ = 1 copy run from the same state over the period; ``oracle``
(truth) minus the period's mean of ``‖(x̂ − x) / σ₀‖``; ``nees`` (truth) minus
``|mean NEES / 4 − 1|``. Installed packages can add rewards through the entry-point group
``qkf.gyro_rewards``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qkf.core.registry import Registry
from qkf.core.stats import nees


@dataclass(frozen=True)
class GyroPeriod:
    """One decision period (internal units; P = the period's epochs inside the episode)."""

    loglik_gain: float  # ℓ_agent − ℓ_nominal over the period
    errors: np.ndarray  # (P, 4) x̂ − x
    cov: np.ndarray  # (P, 4, 4)
    prior_sd: np.ndarray  # (4,)
    steps: int
    dt: float


@dataclass(frozen=True)
class GyroReward:
    """A reward function of one period and whether it reads the truth (simulation only)."""

    fn: Callable[[GyroPeriod], float]
    description: str
    uses_truth: bool = False


GYRO_REWARDS: Registry[GyroReward] = Registry("gyro reward", group="qkf.gyro_rewards")
"""Rewards of ``qkf/RedundantGyroCalibration-v0`` by name."""


def likelihood_reward(o: GyroPeriod) -> float:
    """``(ℓ_agent − ℓ_nominal) / (steps Δt)``, per second."""
    return o.loglik_gain / (o.steps * o.dt)


def oracle_reward(o: GyroPeriod) -> float:
    """Minus the period's mean of ``‖(x̂ − x) / σ₀‖``."""
    return -float(np.mean(np.linalg.norm(o.errors / o.prior_sd, axis=1)))


def nees_reward(o: GyroPeriod) -> float:
    """Minus ``|mean NEES / 4 − 1|`` over the period."""
    return -abs(float(np.mean(nees(o.errors, o.cov))) / 4.0 - 1.0)


GYRO_REWARDS.register(
    "likelihood", GyroReward(likelihood_reward, "innovation log-likelihood gain over κ = 1")
)
GYRO_REWARDS.register(
    "oracle", GyroReward(oracle_reward, "minus the error over the prior sd", uses_truth=True)
)
GYRO_REWARDS.register("nees", GyroReward(nees_reward, "minus |NEES/4 − 1|", uses_truth=True))
