r"""The innovation-based adaptive κ of the gyro calibration UKF, a classical baseline for the gyro
policies (docs/redundant_gyros.md, "Innovation-based adaptive κ").

Covariance matching through the innovations: if the filter's process noise is right, the
normalised innovation squared ``ν²/S`` has mean 1; a mean above 1 says the filter trusts its
state too much (too little process noise), below 1 too little. Each decision period ``t`` the
rule smooths the period's mean NIS ``n_t`` in the log domain and scales κ by it,

    m_t = (1 − a) m_{t−1} + a log n_t,     a = 1 − 2^(−1/h)   (half-life h periods, m_0 = 0)
    κ_{t+1} = clip(κ_t · exp(γ m_t), κ_min, κ_max),     κ_1 = κ_0,

with the gain ``γ``, the half-life ``h`` and the start ``κ_0`` its settings and ``[κ_min,
κ_max]`` the action set's range. It is the scalar form of a Sage–Husa / covariance-matching
update of Q, with κ the one factor a gyro policy sets too. The filter is the compiled UKF of
the environments (:func:`~qkf.redundant_gyros.ukf_compiled.run_periods`) on the environments'
episodes (:class:`~qkf.redundant_gyros.episodes.EpisodeSampler`), so its criterion ``J`` (the
hindsight's: settled mean square of the four states over their prior sd) is comparable with a
policy's on the same seeds. :func:`tune` picks the settings on tuning seeds by a grid of at
least 50 points.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.ukf_compiled import SUMS, CompiledSetup, run_periods


@dataclass(frozen=True)
class NisRule:
    """The rule's settings: gain ``gamma``, half-life ``halflife`` (periods), start
    ``kappa0``."""

    gamma: float
    halflife: float
    kappa0: float


GAINS = (0.0, 0.25, 0.5, 1.0, 2.0)
HALF_LIVES = (1.0, 3.0, 10.0)
"""The tuning grid's gains and half-lives; the starts are the action set's κ (11): 165 points.
A gain of 0 is the constant κ₀, so the tuned rule is never worse than the best constant κ on
its tuning episodes."""


@dataclass(frozen=True)
class EpisodeBatch:
    """The episodes of some environment seeds, stacked for the compiled UKF."""

    cfg: GyrosConfig
    sampler: EpisodeSampler
    z: np.ndarray  # (N, K)
    rate: np.ndarray  # (N, K, 3)
    truth: np.ndarray  # (N, K, 4)
    settled: np.ndarray  # (N,) first judged epoch
    period: int

    @classmethod
    def of(cls, cfg: GyrosConfig, seeds: Sequence[int]) -> EpisodeBatch:
        eps = [hs.episode(cfg, int(s)) for s in seeds]
        return cls(
            cfg,
            EpisodeSampler(cfg),
            np.stack([e.inputs.z for e in eps]),
            np.stack([e.inputs.rate for e in eps]),
            np.stack([e.inputs.truth for e in eps]),
            np.array([e.settled_from for e in eps]),
            eps[0].period,
        )


def run_rule(cfg: GyrosConfig, seeds: Sequence[int], rule: NisRule) -> np.ndarray:
    """``J`` per episode (len(seeds),) of the rule on the episodes of environment seeds
    ``seeds`` (``inf`` where the filter fails)."""
    return run_rule_on(EpisodeBatch.of(cfg, seeds), rule)


def run_rule_on(b: EpisodeBatch, rule: NisRule) -> np.ndarray:
    """:func:`run_rule` on episodes drawn before."""
    sampler, z, rate, truth, settled, period = b.sampler, b.z, b.rate, b.truth, b.settled, b.period
    n, k_n = z.shape
    setup = sampler.setup
    compiled = CompiledSetup.of(setup)
    kappas = np.asarray(b.cfg.environment.actions.values(), dtype=float)
    lo, hi = float(kappas.min()), float(kappas.max())
    x = np.tile(setup.x0, (n, 1))
    p = np.tile(np.diag(setup.p0_sd**2), (n, 1, 1))
    failed = np.zeros(n, dtype=bool)
    nominal_failed = np.zeros(n, dtype=bool)
    sums = np.zeros((n, len(SUMS)))
    err = np.empty((n, period, 4))
    cov = np.empty((n, 1, 4, 4))
    inv_sd = 1.0 / setup.p0_sd
    a = 1.0 - 2.0 ** (-1.0 / rule.halflife)
    kappa = np.full(n, rule.kappa0)
    m = np.zeros(n)
    total = np.zeros(n)
    for k0 in range(0, k_n, period):
        k1 = min(k0 + period, k_n)
        start, stop = np.full(n, k0), np.full(n, k1)
        run_periods(
            x, p, z, rate, sampler.dt, truth, inv_sd, kappa, start, stop, False, False,
            *compiled.geometry, compiled.weights, failed, nominal_failed, sums, err, cov,
        )  # fmt: skip
        epoch = k0 + np.arange(period)
        sq = np.sum((err * inv_sd) ** 2, axis=2)
        total += np.nansum(np.where(epoch[None, :] >= settled[:, None], sq, 0.0), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_nis = np.log(sums[:, 0] / (k1 - k0))
        m = (1.0 - a) * m + a * np.where(np.isfinite(log_nis), log_nis, 0.0)
        kappa = np.clip(kappa * np.exp(rule.gamma * m), lo, hi)
    j = total / ((k_n - settled) * 4.0)
    return np.where(failed, np.inf, j)


def tune(cfg: GyrosConfig, seeds: Sequence[int]) -> tuple[NisRule, float]:
    """The grid point (:data:`GAINS` × :data:`HALF_LIVES` × the action set as starts) with the
    lowest mean ``J`` over the episodes ``seeds``, and that mean."""
    kappas = np.asarray(cfg.environment.actions.values(), dtype=float)
    batch = EpisodeBatch.of(cfg, seeds)
    best: tuple[NisRule, float] | None = None
    for gamma, halflife, k0 in itertools.product(GAINS, HALF_LIVES, kappas):
        rule = NisRule(gamma, halflife, float(k0))
        score = float(np.mean(run_rule_on(batch, rule)))
        if best is None or score < best[1]:
            best = (rule, score)
    assert best is not None
    return best


__all__ = ["GAINS", "HALF_LIVES", "EpisodeBatch", "NisRule", "run_rule", "run_rule_on", "tune"]
