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
the environments (:class:`~qkf.redundant_gyros.batched_ukf.BatchedUKF`) on the environments'
episodes (:class:`~qkf.redundant_gyros.episodes.EpisodeSampler`), so its criterion ``J`` (the
hindsight's: settled mean square of the four states over their prior sd) is comparable with a
policy's on the same seeds. :func:`tune` picks the settings on tuning seeds by a grid of at
least 50 points.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros.batched_ukf import BatchedUKF
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.ukf_compiled import SUMS

T = TypeVar("T")


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
    """The episodes of some environment seeds, loaded into one batched UKF, and where each
    one's judged window starts."""

    cfg: GyrosConfig
    ukf: BatchedUKF
    settled: np.ndarray  # (N,) first judged epoch

    @classmethod
    def of(cls, cfg: GyrosConfig, seeds: Sequence[int], keep_cov: bool = False) -> EpisodeBatch:
        """The episodes of ``env.reset(seed=s)`` for each of ``seeds``."""
        return cls.of_episodes(cfg, [hs.episode(cfg, int(s)) for s in seeds], keep_cov)

    @classmethod
    def of_episodes(
        cls, cfg: GyrosConfig, eps: Sequence[hs.Episode], keep_cov: bool = False
    ) -> EpisodeBatch:
        """Episodes drawn before, in one batched UKF (``keep_cov``: it keeps each epoch's
        covariance and estimate, :class:`~qkf.redundant_gyros.batched_ukf.BatchedUKF`)."""
        ukf = BatchedUKF(EpisodeSampler(cfg), len(eps), eps[0].period, keep_cov)
        for row, e in enumerate(eps):
            ukf.load(row, e.inputs)
        return cls(cfg, ukf, np.array([e.settled_from for e in eps]))

    def restart_for_covariances(self, rule: str) -> None:
        """Every filter back to its prior, for a ``rule`` that reads each epoch's covariance
        and estimate: ``ValueError`` naming it if the UKF does not keep them (``keep_cov``)."""
        if not self.ukf.keep_cov:
            raise ValueError(f"the {rule} rule needs the epochs' covariances (keep_cov=True)")
        self.ukf.restart(np.arange(self.ukf.n))

    def actions(self) -> list[float]:
        """The κ of the action set, in its order: the starts of the tuning grids."""
        return [float(k) for k in np.asarray(self.cfg.environment.actions.values(), dtype=float)]

    def kappa_range(self) -> tuple[float, float]:
        """The smallest and largest κ of the action set: where the adaptive rules clip κ."""
        kappas = self.actions()
        return min(kappas), max(kappas)

    def best_rule(
        self, rules: Iterable[T], run: Callable[[EpisodeBatch, T], np.ndarray]
    ) -> tuple[T, float]:
        """The rule of ``rules`` with the lowest mean ``J`` over these episodes when ``run``
        (``run(batch, rule)``: ``J`` per episode), and that mean (:func:`grid_minimum`): the
        tuning of the grid-tuned gyro rules."""
        return grid_minimum(rules, lambda rule: float(np.mean(run(self, rule))))

    def criterion(self, total: np.ndarray) -> np.ndarray:
        """``J`` per episode (n,) from ``total`` (n,), the sum over the episodes of
        :meth:`BatchedUKF.settled_square`: its mean over the judged epochs and the four states;
        ``inf`` where the filter failed."""
        j = total / ((self.ukf.n_steps - self.settled) * 4.0)
        return np.where(self.ukf.failed, np.inf, j)


def run_rule(cfg: GyrosConfig, seeds: Sequence[int], rule: NisRule) -> np.ndarray:
    """``J`` per episode (len(seeds),) of the rule on the episodes of environment seeds
    ``seeds`` (``inf`` where the filter fails)."""
    return run_rule_on(EpisodeBatch.of(cfg, seeds), rule)


def run_rule_on(b: EpisodeBatch, rule: NisRule) -> np.ndarray:
    """:func:`run_rule` on episodes drawn before."""
    ukf = b.ukf
    ukf.restart(np.arange(ukf.n))
    lo, hi = b.kappa_range()
    a = 1.0 - 2.0 ** (-1.0 / rule.halflife)
    kappa = np.full(ukf.n, rule.kappa0)
    m = np.zeros(ukf.n)
    total = np.zeros(ukf.n)
    nis = SUMS.index("nis")
    for _ in range(-(-ukf.n_steps // ukf.period)):
        k0, steps = ukf.advance(kappa)
        total += ukf.settled_square(k0, b.settled)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_nis = np.log(ukf.sums[:, nis] / steps)
        m = (1.0 - a) * m + a * np.where(np.isfinite(log_nis), log_nis, 0.0)
        kappa = np.clip(kappa * np.exp(rule.gamma * m), lo, hi)
    return b.criterion(total)


def tune(cfg: GyrosConfig, seeds: Sequence[int]) -> tuple[NisRule, float]:
    """The grid point (:data:`GAINS` × :data:`HALF_LIVES` × the action set as starts) with the
    lowest mean ``J`` over the episodes ``seeds``, and that mean."""
    return tune_on(EpisodeBatch.of(cfg, seeds))


def tune_on(batch: EpisodeBatch) -> tuple[NisRule, float]:
    """:func:`tune` on episodes drawn before."""
    grid = itertools.product(GAINS, HALF_LIVES, batch.actions())
    return batch.best_rule((NisRule(g, h, k0) for g, h, k0 in grid), run_rule_on)


def grid_minimum(points: Iterable[T], score: Callable[[T], float]) -> tuple[T, float]:
    """The point of ``points`` with the lowest ``score`` (the first on ties), and that score:
    the tuning of the grid-tuned gyro rules."""
    best: tuple[T, float] | None = None
    for point in points:
        value = score(point)
        if best is None or value < best[1]:
            best = (point, value)
    if best is None:
        raise ValueError("an empty tuning grid")
    return best


__all__ = [
    "GAINS",
    "HALF_LIVES",
    "EpisodeBatch",
    "NisRule",
    "grid_minimum",
    "run_rule",
    "run_rule_on",
    "tune",
    "tune_on",
]
