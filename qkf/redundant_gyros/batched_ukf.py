"""N calibration episodes stepped period by period through the compiled UKF
(docs/redundant_gyros.md, "The compiled UKF").

:class:`BatchedUKF` holds the episodes' inputs (from an
:class:`~qkf.redundant_gyros.episodes.EpisodeSampler`), each filter's state and position, and
the buffers :func:`~qkf.redundant_gyros.ukf_compiled.run_periods` fills; :meth:`BatchedUKF.advance`
steps every episode over its next decision period in one compiled call. The environments
(:class:`envs.redundant_gyros.episodes.GyroEpisodes`) and the classical adaptive κ
(:mod:`qkf.redundant_gyros.nis_adaptive`) both step their episodes through it.
"""

from __future__ import annotations

import numpy as np

from qkf.redundant_gyros.episodes import EpisodeInputs, EpisodeSampler
from qkf.redundant_gyros.ukf_compiled import SUMS, CompiledSetup, run_periods


class BatchedUKF:
    """``n`` episodes of ``sampler``'s config, ``period`` epochs per decision period.

    After :meth:`advance`: ``sums`` (n, len(SUMS)) the period's :data:`SUMS`, ``err`` (n, period, 4)
    ``x̂ − x`` per epoch (NaN where not run) and, with ``keep_cov``, ``cov`` (n, period, 4, 4)
    the updated covariance and ``est`` (n, period, 4) the estimate per epoch.
    """

    def __init__(
        self, sampler: EpisodeSampler, n: int, period: int, keep_cov: bool = False
    ) -> None:
        self.sampler, self.setup, self.period = sampler, sampler.setup, period
        self.n, self.n_steps = n, sampler.n_epochs  # episodes, calibrated epochs per episode
        self.keep_cov = keep_cov
        self.compiled = CompiledSetup.of(self.setup)
        k = self.n_steps
        self.z, self.rate = np.zeros((n, k)), np.zeros((n, k, 3))
        self.truth = np.zeros((n, k, 4))
        self.onset_s = np.full(n, np.nan)
        self.x, self.p = np.zeros((n, 4)), np.zeros((n, 4, 4))
        self.failed = np.zeros(n, dtype=bool)
        self.nominal_failed = np.zeros(n, dtype=bool)
        self.k = np.zeros(n, dtype=np.int64)  # next epoch of each episode
        self.inv_sd = 1.0 / self.setup.p0_sd
        self.sums = np.zeros((n, len(SUMS)))
        self.err = np.empty((n, period, 4))
        self.cov = np.empty((n, period, 4, 4) if keep_cov else (n, 1, 4, 4))
        self.est = np.empty((n, period, 4) if keep_cov else (n, 1, 4))

    def load(self, row: int, inputs: EpisodeInputs) -> None:
        """Episode ``inputs`` into row ``row`` (then :meth:`restart` it)."""
        self.z[row], self.rate[row], self.truth[row] = inputs.z, inputs.rate, inputs.truth
        self.onset_s[row] = np.nan if inputs.onset_s is None else inputs.onset_s

    def restart(self, rows: np.ndarray) -> None:
        """Filters ``rows`` back to the prior, at their episode's first epoch."""
        self.x[rows] = self.setup.x0
        self.p[rows] = np.diag(self.setup.p0_sd**2)
        self.failed[rows] = False
        self.k[rows] = 0

    def advance(self, kappa: np.ndarray, nominal: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Every episode over its next period with ``kappa`` (n,) (and, with ``nominal``, a
        κ = 1 copy from the period's start); the period's first epoch and its epochs, (n,)
        each (0 for an episode past its end)."""
        k0 = self.k.copy()
        k1 = np.minimum(k0 + self.period, self.n_steps)
        c = self.compiled
        run_periods(
            self.x, self.p, self.z, self.rate, self.sampler.dt, self.truth, self.inv_sd,
            np.asarray(kappa, dtype=float), k0, k1, nominal, self.keep_cov,
            *c.geometry, c.weights, self.failed, self.nominal_failed, self.sums, self.err,
            self.cov, self.est,
        )  # fmt: skip
        self.k = k1
        return k0, k1 - k0

    def period_epochs(self, k0: np.ndarray) -> np.ndarray:
        """The epochs (n, period) of the period that started at ``k0`` (n,), the episode's last
        epoch repeated past its end (where ``err``, ``cov`` and ``est`` are NaN)."""
        return np.minimum(k0[:, None] + np.arange(self.period)[None, :], self.n_steps - 1)

    def nominal_process_noise(self, epochs: np.ndarray) -> np.ndarray:
        """``Q₀_k,ii = q²_i Δt_k`` (..., 4) at ``epochs`` (...): the process noise per epoch
        at κ = 1 (the UKF's own, :mod:`~qkf.redundant_gyros.ukf`)."""
        return np.asarray(self.setup.q_sd**2 * self.sampler.dt[epochs][..., None])

    def settled_square(self, k0: np.ndarray, settled: np.ndarray) -> np.ndarray:
        """``Σ ‖(x̂ − x)/σ₀‖²`` (n,) over the last period's epochs from ``settled`` (n,) on,
        the period having started at ``k0`` (n,): a term of the hindsight's ``J``."""
        epoch = k0[:, None] + np.arange(self.period)[None, :]
        sq = np.sum((self.err * self.inv_sd) ** 2, axis=2)  # NaN where not run
        return np.nansum(np.where(epoch >= settled[:, None], sq, 0.0), axis=1)


__all__ = ["BatchedUKF"]
