r"""The Sage–Husa adaptive process noise of the gyro calibration UKF, projected onto κ: a
classical baseline for the gyro policies (docs/redundant_gyros.md, "Sage–Husa κ").

Sage and Husa's estimator of the process noise of a filter with a random-walk state (the
calibration coefficients: ``x_k = x_{k−1} + w_k``, ``Φ = I``) replaces the innovation
covariance ``S_k`` in ``Q = P⁻_k − P_{k−1} = P_k + K_k S_k K_kᵀ − P_{k−1}`` by the sample
``ν_k ν_kᵀ``; with ``K_k ν_k = x̂_k − x̂_{k−1}`` (the state's correction: its prediction is
unchanged) one epoch's estimate is

    Q̂_k = Δx̂_k Δx̂_kᵀ + P_k − P_{k−1},     Δx̂_k = x̂_k − x̂_{k−1}.

The filter's process noise is ``κ · diag(q²) · dt`` (the action every gyro method and policy
sets), so the estimate is projected onto that family: the period's

    κ̂_t = mean over its epochs k and the four states i of  Q̂_k,ii / (q²_i dt_k),

held inside the action set's range (which also keeps the process noise positive, the
estimator's known failure) and faded as Sage–Husa does:

    κ_{t+1} = clip((1 − d_s) κ_t + d_s clip(κ̂_t, κ_min, κ_max), κ_min, κ_max),
    d_s = (1 − β) / (1 − β^(s+1)),   s = t − w,

``t = 0, 1, …`` the decision periods, ``κ_0`` the start, held for the first ``w`` periods
(the warm-up: while the covariance falls from the prior, ``P_k − P_{k−1}`` is orders of
magnitude larger than ``Q`` and one period's estimate is noise: −2·10¹⁰ × the nominal in the
first period of ``gyro_noise_levels``). The forgetting factor ``β``, the warm-up ``w`` and
``κ_0`` are its settings; ``β = 1`` (``d = 0``) is the constant ``κ_0``, so the tuned rule is
never worse than the best constant κ on its tuning episodes. κ changes only at decision
periods, like every method and policy of the gym. The filter is the compiled UKF of the
environments on their episodes (:class:`~qkf.redundant_gyros.nis_adaptive.EpisodeBatch`);
:func:`tune_on` picks the settings on tuning episodes from a grid of 198 points.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from qkf.redundant_gyros.nis_adaptive import EpisodeBatch

FORGETTING = (0.5, 0.8, 0.9, 0.95, 0.98, 1.0)
"""The tuning grid's forgetting factors ``β`` (1: the constant ``κ_0``)."""
WARM_UPS = (0, 10, 30)
"""The tuning grid's warm-ups, decision periods; with the action set's κ (11) as starts: 198
points."""


@dataclass(frozen=True)
class SageHusaRule:
    """The rule's settings: forgetting factor ``beta`` in (0, 1], start ``kappa0``, held for
    the first ``warm_up`` decision periods."""

    beta: float
    kappa0: float
    warm_up: int = 0


def period_kappa_estimate(
    est: np.ndarray, cov: np.ndarray, x_prev: np.ndarray, p_prev: np.ndarray, q_step: np.ndarray
) -> np.ndarray:
    """``κ̂`` (n,) of one period (module docstring) from each episode's estimates ``est``
    (n, P, 4) and updated covariances ``cov`` (n, P, 4, 4) over the period's epochs (NaN where
    not run), the estimate and covariance before its first epoch ``x_prev`` (n, 4), ``p_prev``
    (n, 4, 4), and the nominal process noise per epoch ``q_step`` (n, P, 4): ``q²_i dt_k``.
    NaN for an episode that ran no epoch."""
    x_before = np.concatenate([x_prev[:, None, :], est[:, :-1, :]], axis=1)  # x̂_{k−1}
    p_before = np.concatenate([p_prev[:, None, :, :], cov[:, :-1, :, :]], axis=1)  # P_{k−1}
    dx = est - x_before
    q_diag = dx * dx + np.diagonal(cov, axis1=2, axis2=3) - np.diagonal(p_before, axis1=2, axis2=3)
    ratio = q_diag / q_step  # (n, P, 4): Q̂_k,ii / (q²_i dt_k)
    ran = np.isfinite(ratio).all(axis=2)  # epochs run
    total = np.where(ran[:, :, None], ratio, 0.0).sum(axis=(1, 2))
    count = 4.0 * ran.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def run_rule_on(b: EpisodeBatch, rule: SageHusaRule) -> np.ndarray:
    """``J`` per episode of the rule on episodes loaded into ``b`` (its UKF keeping each
    epoch's covariance and estimate: ``EpisodeBatch.of_episodes(..., keep_cov=True)``);
    ``inf`` where the filter fails."""
    ukf = b.ukf
    b.restart_for_covariances("Sage–Husa")
    lo, hi = b.kappa_range()
    kappa = np.full(ukf.n, rule.kappa0)
    total = np.zeros(ukf.n)
    for t in range(-(-ukf.n_steps // ukf.period)):
        x_prev, p_prev = ukf.x.copy(), ukf.p.copy()
        k0, _ = ukf.advance(kappa)
        total += ukf.settled_square(k0, b.settled)
        q_step = ukf.nominal_process_noise(ukf.period_epochs(k0))
        s = t - rule.warm_up
        if s < 0:  # warm-up: κ_0 held
            continue
        estimate = period_kappa_estimate(ukf.est, ukf.cov, x_prev, p_prev, q_step)
        held = np.clip(np.where(np.isfinite(estimate), estimate, kappa), lo, hi)
        d = 0.0 if rule.beta >= 1.0 else (1.0 - rule.beta) / (1.0 - rule.beta ** (s + 1))
        kappa = np.clip((1.0 - d) * kappa + d * held, lo, hi)
    return b.criterion(total)


def tune_on(batch: EpisodeBatch) -> tuple[SageHusaRule, float]:
    """The grid point (:data:`FORGETTING` × the action set as starts × :data:`WARM_UPS`) with
    the lowest mean ``J`` over the episodes of ``batch``, and that mean (the first such point
    on ties: ``β = 1`` gives one result whatever the warm-up)."""
    grid = itertools.product(FORGETTING, batch.actions(), WARM_UPS)
    rules = (SageHusaRule(float(beta), k0, int(warm)) for beta, k0, warm in grid)
    return batch.best_rule(rules, run_rule_on)


__all__ = [
    "FORGETTING",
    "WARM_UPS",
    "SageHusaRule",
    "period_kappa_estimate",
    "run_rule_on",
    "tune_on",
]
