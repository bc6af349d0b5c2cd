r"""Rewards of the transfer-alignment environments: a registry (docs/environment.md, "Rewards").

A reward turns what happened over one decision period into one number per episode. It receives
a :class:`PeriodOutcome` and returns an array (N,); non-finite values and diverged episodes are
replaced by the divergence reward afterwards. Register your own with::

    from envs import REWARDS, PeriodOutcome, Reward   # envs.transfer_alignment.rewards

    def calm(o: PeriodOutcome) -> np.ndarray:          # minus the mean attitude NIS
        return -o.period_mean(o.record.nis_att)

    REWARDS.register("calm", Reward(calm, "minus the mean attitude NIS"))

then ``gym.make("qkf/TransferAlignment-v2", reward="calm")`` or ``reward: calm`` in a training
config. Installed packages can add rewards through the entry-point group ``qkf.rewards``.

Built in:

* ``likelihood`` (default, no truth): ``(ℓ_agent − ℓ_nominal) / T_c``, the innovation
  log-likelihood gain over a κ = 1 filter run from the same state, per second — the QKF reward;
* ``oracle`` (truth): minus the period's mean of ``‖Δp‖ / ‖σ_CRLB,p‖``;
* ``nees`` (truth): minus ``|mean NEES / 15 − 1|`` over the period;
* ``misalignment_gain`` / ``calibration_gain`` (truth): the reduction of the squared error of
  the misalignment (or all calibration) terms over the settled window (``run.settled_s`` on),
  against a free-running filter at the nominal κ (the ``kf`` method) on the same data, scaled so
  that an episode's return is ``MSE_kf − MSE_agent`` in display units² — the benchmark's
  settled metric, squared, as a difference to ``kf``;
* ``state_gain`` (truth): the same over the whole state, every state in units of its final
  nominal CRLB (the weights of the judged metric ``state_settled``,
  :func:`qkf.transfer_alignment.judging.state_weights`): an episode's return is
  ``MS_kf − MS_agent`` of ``state_settled``, so a policy cannot buy one group with another;
* ``relative_state_gain`` (truth): ``state_gain`` divided by the kf's settled mean square of
  the whole episode (known when the episode starts: the reference does not depend on the
  agent), so that an episode's return is ``1 − MS_agent / MS_kf`` and every episode weighs
  the same, whatever the size of its change.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qkf.core.registry import Registry
from qkf.core.stats import nees
from qkf.transfer_alignment.filter import FilterRecord
from qkf.transfer_alignment.model import CALIB
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUPS


@dataclass(frozen=True)
class PeriodOutcome:
    """One decision period of N episodes (SI units; ``P`` = epochs in the period)."""

    record: FilterRecord  # the agent's filter over the period (covariance if ``needs_cov``)
    loglik_gain: np.ndarray | None  # (N,) ℓ_agent − ℓ_nominal over the valid epochs, if needed
    errors: np.ndarray  # (N, P, 15) true estimation errors (NaN unless the reward uses_truth)
    bound: np.ndarray  # (N, P, 15) CRLB 1-σ
    valid: np.ndarray  # (N, P) bool: epochs inside the episode
    steps: np.ndarray  # (N,) valid epochs (at least 1)
    dt: float  # s
    reference_errors: np.ndarray | None = None  # (N, P, 15) of the reference filter, if needed
    settled: np.ndarray | None = None  # (N, P) bool: valid epochs of the settled window
    settled_epochs: int = 1  # epochs of the run's settled window
    weights: np.ndarray | None = None  # (15,) SI: the state_settled weights, if needed
    reference_ms: np.ndarray | None = None  # (N,) the reference's settled state_settled²

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
    needs_likelihood: bool = False  # the κ = 1 shadow filter runs for ``loglik_gain``
    needs_reference: bool = False  # a free-running nominal-κ filter runs for ``reference_errors``


REWARDS: Registry[Reward] = Registry("reward", group="qkf.rewards")
"""Rewards by name, for ``reward=`` of the environments and ``reward:`` of training configs."""


def likelihood_reward(o: PeriodOutcome) -> np.ndarray:
    """``(ℓ_agent − ℓ_nominal) / (steps · Δt)``, per second."""
    assert o.loglik_gain is not None
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


def settled_gain(states: slice) -> Callable[[PeriodOutcome], np.ndarray]:
    """The reward that sums, over an episode, to the reduction of the settled-window mean
    square error of ``states`` (display units², mean over the states) against the reference
    filter: per period ``Σ_settled (‖e_ref‖² − ‖e‖²) / (n_states · N_settled)``."""
    n_states = len(range(15)[states])

    def gain(o: PeriodOutcome) -> np.ndarray:
        assert o.reference_errors is not None and o.settled is not None
        e = o.errors[..., states] / DISPLAY_UNIT[states]
        e_ref = o.reference_errors[..., states] / DISPLAY_UNIT[states]
        diff = np.sum(e_ref**2, axis=-1) - np.sum(e**2, axis=-1)
        return np.sum(np.where(o.settled, diff, 0.0), axis=1) / (n_states * o.settled_epochs)

    return gain


def state_gain(o: PeriodOutcome) -> np.ndarray:
    """Per period ``Σ_settled Σ_i ((e_ref,i / w_i)² − (e_i / w_i)²) / (15 · N_settled)``: summed
    over an episode, ``MS_kf − MS_agent`` of the judged whole-state metric ``state_settled``
    (w the final nominal CRLB per state)."""
    assert o.reference_errors is not None and o.settled is not None and o.weights is not None
    diff = np.sum((o.reference_errors / o.weights) ** 2, axis=-1) - np.sum(
        (o.errors / o.weights) ** 2, axis=-1
    )
    return np.sum(np.where(o.settled, diff, 0.0), axis=1) / (o.weights.size * o.settled_epochs)


def relative_state_gain(o: PeriodOutcome) -> np.ndarray:
    """:func:`state_gain` over the reference's settled mean square of the whole episode: summed
    over an episode, ``1 − MS_agent / MS_kf``; every episode weighs the same."""
    assert o.reference_ms is not None
    return state_gain(o) / o.reference_ms


REWARDS.register(
    "likelihood",
    Reward(
        likelihood_reward,
        "innovation log-likelihood gain over κ = 1, per second",
        needs_likelihood=True,
    ),
)
REWARDS.register(
    "oracle", Reward(oracle_reward, "minus calibration error over the CRLB", uses_truth=True)
)
REWARDS.register(
    "nees", Reward(nees_reward, "minus |NEES/15 − 1|", uses_truth=True, needs_cov=True)
)
REWARDS.register(
    "misalignment_gain",
    Reward(
        settled_gain(GROUPS["ma_urad"]),
        "settled misalignment mean-square reduction against the nominal-κ filter, µrad²",
        uses_truth=True,
        needs_reference=True,
    ),
)
REWARDS.register(
    "calibration_gain",
    Reward(
        settled_gain(CALIB),
        "settled calibration (ppm, µrad) mean-square reduction against the nominal-κ filter",
        uses_truth=True,
        needs_reference=True,
    ),
)
REWARDS.register(
    "state_gain",
    Reward(
        state_gain,
        "settled whole-state (state_settled) mean-square reduction against the nominal-κ filter",
        uses_truth=True,
        needs_reference=True,
    ),
)
REWARDS.register(
    "relative_state_gain",
    Reward(
        relative_state_gain,
        "state_gain over the kf's settled mean square of the episode: 1 − MS_agent / MS_kf",
        uses_truth=True,
        needs_reference=True,
    ),
)
