r"""Rewards of the transfer-alignment environments: a registry (docs/environment.md, "Rewards").

A reward turns what happened over one decision period into one number per episode. It receives
a :class:`PeriodOutcome` and returns an array (N,); non-finite values and diverged episodes are
replaced by the divergence reward afterwards. Register your own with::

    from envs.rewards import REWARDS, Reward

    def calm(o: PeriodOutcome) -> np.ndarray:          # minus the mean attitude NIS
        return -o.period_mean(o.record.nis_att)

    REWARDS.register("calm", Reward(calm, "minus the mean attitude NIS"))

then ``gym.make("qkf/TransferAlignment-v0", reward="calm")`` or ``reward: calm`` in a training
config. Installed packages can add rewards through the entry-point group ``qkf.rewards``.

Built in:

* ``likelihood`` (default, no truth): ``(ℓ_agent − ℓ_nominal) / T_c``, the innovation
  log-likelihood gain over a κ = 1 filter run from the same state, per second — the QKF reward;
* ``oracle`` (truth): minus the period's mean of ``‖Δp‖ / ‖σ_CRLB,p‖``;
* ``nees`` (truth): minus ``|mean NEES / 15 − 1|`` over the period.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qkf.core.registry import Registry
from qkf.core.stats import nees
from qkf.transfer_alignment.filter import FilterRecord


@dataclass(frozen=True)
class PeriodOutcome:
    """One decision period of N episodes (SI units; ``P`` = epochs in the period)."""

    record: FilterRecord  # the agent's filter over the period (covariance if ``needs_cov``)
    loglik_gain: np.ndarray  # (N,) ℓ_agent − ℓ_nominal summed over the valid epochs
    errors: np.ndarray  # (N, P, 15) true estimation errors
    bound: np.ndarray  # (N, P, 15) CRLB 1-σ
    valid: np.ndarray  # (N, P) bool: epochs inside the episode
    steps: np.ndarray  # (N,) valid epochs (at least 1)
    dt: float  # s

    def period_mean(self, x: np.ndarray) -> np.ndarray:
        """Mean over the valid epochs of a per-epoch quantity (N, P) → (N,)."""
        return np.sum(np.where(self.valid, x, 0.0), axis=1) / self.steps


@dataclass(frozen=True)
class Reward:
    """A reward function and what it needs."""

    fn: Callable[[PeriodOutcome], np.ndarray]
    description: str
    uses_truth: bool = False  # simulation only: never available in flight
    needs_cov: bool = False  # the full covariance is recorded over the period (slower)


REWARDS: Registry[Reward] = Registry("reward", group="qkf.rewards")
"""Rewards by name, for ``reward=`` of the environments and ``reward:`` of training configs."""


def likelihood_reward(o: PeriodOutcome) -> np.ndarray:
    """``(ℓ_agent − ℓ_nominal) / (steps · Δt)``, per second."""
    return o.loglik_gain / (o.steps * o.dt)


def oracle_reward(o: PeriodOutcome) -> np.ndarray:
    """Minus the period's mean of ``‖Δp‖ / ‖σ_CRLB,p‖`` (calibration error over its bound)."""
    ratio = np.linalg.norm(o.errors[..., 6:15], axis=-1) / np.linalg.norm(
        o.bound[..., 6:15], axis=-1
    )
    return -np.sum(np.where(o.valid, ratio, 0.0), axis=1) / o.steps


def nees_reward(o: PeriodOutcome) -> np.ndarray:
    """Minus ``|mean NEES / 15 − 1|`` over the period (the filter's own consistency)."""
    assert o.record.cov is not None
    ne = nees(o.errors, o.record.cov)
    return -np.abs(np.sum(np.where(o.valid, ne, 0.0), axis=1) / o.steps / 15.0 - 1.0)


REWARDS.register(
    "likelihood", Reward(likelihood_reward, "innovation log-likelihood gain over κ = 1, per second")
)
REWARDS.register(
    "oracle", Reward(oracle_reward, "minus calibration error over the CRLB", uses_truth=True)
)
REWARDS.register(
    "nees", Reward(nees_reward, "minus |NEES/15 − 1|", uses_truth=True, needs_cov=True)
)
