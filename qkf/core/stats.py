"""Statistics shared by every estimation problem: NEES and running sums over Monte Carlo trials."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared ``eᵀ P⁻¹ e`` over the last axis; NaN if P is not PD.

    ``err`` (..., n) and ``cov`` (..., n, n) in the same units.
    """
    shape = err.shape[:-1]
    e = err.reshape(-1, err.shape[-1])
    p = cov.reshape(-1, err.shape[-1], err.shape[-1])
    out = np.full(e.shape[0], np.nan)
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(p), axis=(1, 2))
    if ok.any():
        # Scale to unit diagonal first: P may span many orders of magnitude.
        sd = np.sqrt(np.einsum("kii->ki", p[ok]))
        pn = p[ok] / (sd[:, :, None] * sd[:, None, :])
        en = e[ok] / sd
        try:
            chol = np.linalg.cholesky(pn)
        except np.linalg.LinAlgError:
            return _nees_slow(e, p, shape)
        y = np.linalg.solve(chol, en[..., None])[..., 0]
        out[ok] = np.sum(y * y, axis=-1)
    return out.reshape(shape)


def _nees_slow(e: np.ndarray, p: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    out = np.full(e.shape[0], np.nan)
    for i in range(e.shape[0]):
        try:
            c = np.linalg.cholesky(p[i])
        except np.linalg.LinAlgError:
            continue
        y = np.linalg.solve(c, e[i])
        out[i] = float(y @ y)
    return out.reshape(shape)


@dataclass
class ErrorAccumulator:
    """Running sums over trials of squared errors per epoch and state (chunk by chunk)."""

    n_epochs: int
    sum_sq: np.ndarray | None = None
    count: int = 0
    diverged: int = 0

    def add_sums(self, sum_sq: np.ndarray, count: int, diverged: int = 0) -> None:
        """Add a chunk already reduced to its sum of squared errors (n_epochs, n_states)."""
        if sum_sq.shape[0] != self.n_epochs:
            raise ValueError(f"expected {self.n_epochs} epochs, got {sum_sq.shape[0]}")
        self.sum_sq = sum_sq.copy() if self.sum_sq is None else self.sum_sq + sum_sq
        self.count += count
        self.diverged += diverged

    def rms(self) -> np.ndarray:
        """RMS over trials (n_epochs, n_states); NaN where any trial was non-finite."""
        if self.sum_sq is None or self.count == 0:
            raise ValueError("no trials accumulated")
        return np.sqrt(self.sum_sq / self.count)


def resample_counts(n_trials: int, n_resamples: int, seed: int) -> np.ndarray:
    """Bootstrap resamples of trial indices as counts: row r says how often each trial is drawn
    in resample r (each row sums to ``n_trials``). Seeded, so intervals are reproducible.

    Counts instead of index lists make every resampled mean one matrix product.
    """
    rng = np.random.default_rng([seed, 0xB0075])
    p = np.full(n_trials, 1.0 / n_trials)
    return rng.multinomial(n_trials, p, size=n_resamples).astype(np.float64)


def bootstrap_rms(ms: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """RMS over trials of each resample: ``sqrt(Σ_i c_ri ms_i / n)``.

    ``ms`` (n_trials, ...) are per-trial mean squares; ``counts`` (R, n_trials) from
    :func:`resample_counts`. Returns (R, ...).
    """
    n = ms.shape[0]
    flat = ms.reshape(n, -1)
    out = np.sqrt(counts @ flat / n)
    return out.reshape(counts.shape[0], *ms.shape[1:])


def ratio_side(lo: float, hi: float) -> int:
    """Where an interval of a ratio lies against 1: −1 below (significantly smaller), +1 above,
    0 when it contains 1."""
    return -1 if hi < 1.0 else 1 if lo > 1.0 else 0


def percentile_interval(samples: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval over the first axis (bootstrap replicates)."""
    tail = 50.0 * (1.0 - level)
    lo, hi = np.percentile(samples, [tail, 100.0 - tail], axis=0)
    return lo, hi


def average_nees_band(
    dim: int, n_trials: np.ndarray, level: float
) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided χ² band of ``level`` for a NEES of ``dim`` states averaged over ``n_trials``
    (any shape, each ≥ 1): ``[χ²_{dim·n}((1 − level)/2), χ²_{dim·n}((1 + level)/2)] / n``."""
    from scipy import stats as sps

    n = np.asarray(n_trials, dtype=float)
    a = (1.0 - level) / 2.0
    return sps.chi2.ppf(a, dim * n) / n, sps.chi2.ppf(1.0 - a, dim * n) / n


def interquartile_mean(values: np.ndarray) -> float:
    """Mean of the middle half of the empirical distribution (IQM, robust across training
    seeds): each of the n sorted values carries mass 1/n, and only the mass between the 25th
    and 75th percentiles is kept, fractions of a value included. For n = 3 this weighs the
    values ⅙, ⅔, ⅙; for n divisible by 4 it is the mean of the middle n/2 values."""
    x = np.sort(np.asarray(values, dtype=float).ravel())
    if x.size == 0 or not np.isfinite(x).all():
        raise ValueError("interquartile_mean needs finite values")
    edges = np.arange(x.size + 1) / x.size
    kept = np.clip(np.minimum(edges[1:], 0.75) - np.maximum(edges[:-1], 0.25), 0.0, None)
    return float(np.sum(kept * x) / 0.5)
