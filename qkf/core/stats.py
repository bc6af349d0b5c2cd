"""Statistics shared by every estimation problem: NEES and running sums over Monte Carlo trials."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

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
    :func:`resample_counts`. Returns (R, ...). A trial whose mean square is not finite (the
    method lost it) makes ``inf`` of exactly the resamples that draw it; the matrix product
    alone would spread ``0 · inf = NaN`` to every resample.
    """
    n = ms.shape[0]
    flat = ms.reshape(n, -1)
    finite = np.isfinite(flat)
    if finite.all():
        out = np.sqrt(counts @ flat / n)
    else:
        out = np.sqrt(counts @ np.where(finite, flat, 0.0) / n)
        out[counts @ (~finite).astype(np.float64) > 0] = np.inf
    return out.reshape(counts.shape[0], *ms.shape[1:])


def ratio_side(lo: float, hi: float) -> int:
    """Where an interval of a ratio lies against 1: −1 below (significantly smaller), +1 above,
    0 when it contains 1."""
    return -1 if hi < 1.0 else 1 if lo > 1.0 else 0


def percentiles(samples: np.ndarray, q: Sequence[float]) -> np.ndarray:
    """``np.percentile(samples, q, axis=0)`` (linear interpolation) that keeps infinities:
    numpy interpolates as ``b − (b − a)(1 − t)``, so a percentile next to an ``inf`` comes out
    NaN (``inf − inf``). Here a percentile whose interpolation reaches ``±inf`` is that
    infinity; a column holding a NaN stays NaN. Columns without an infinity are numpy's own.
    Returns (len(q), ...)."""
    x = np.asarray(samples, dtype=float)
    qs = np.asarray(q, dtype=float)
    flat = x.reshape(x.shape[0], -1)
    inf = np.isinf(flat)
    with np.errstate(invalid="ignore"):
        out = np.percentile(np.where(inf, 0.0, flat), qs, axis=0)
    cols = inf.any(axis=0)
    if cols.any():
        xs = np.sort(flat[:, cols], axis=0)  # NaN last
        lost = np.isnan(xs).any(axis=0)
        n = xs.shape[0]
        for i, qi in enumerate(qs):
            h = (n - 1) * (qi / 100.0)  # numpy's virtual index for linear interpolation
            k = min(int(np.floor(h)), n - 1)
            g = h - k
            a, b = xs[k], xs[min(k + 1, n - 1)]
            with np.errstate(invalid="ignore"):
                d = b - a
                v = a if g == 0.0 else (a + d * g if g < 0.5 else b - d * (1.0 - g))
            v = np.where((a == -np.inf) | (a == np.inf), a, v)
            v = np.where((b == np.inf) & (g > 0.0), np.inf, v)
            out[i, cols] = np.where(lost, np.nan, v)
    return out.reshape(len(qs), *x.shape[1:])


def percentile_interval(samples: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval over the first axis (bootstrap replicates); ``inf`` replicates (a
    resample that drew a lost trial) are kept as such (:func:`percentiles`)."""
    tail = 50.0 * (1.0 - level)
    lo, hi = percentiles(samples, [tail, 100.0 - tail])
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


# --- per-trial comparisons (docs/methods.md, "Per-trial verdicts") ------------------------

WORST_QUANTILE = 0.9
"""The worst decile of per-trial ratios is reported as their 90th percentile: one trial in ten
is worse than it."""

TIE_RTOL = 1e-9
"""Per-trial ratios within this of 1 are ties for ``P(improve)``: the same schedule run by two
compiled twins (or on two CPUs) differs in the last bits, which is not a win (the tolerance of
the project's float pins)."""


def trial_ratios(values: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Per-trial ratios ``values / base`` (n, ...) of paired per-trial scores. A trial lost by
    the method (not finite) counts as ``inf`` (a loss), one lost by the baseline alone as 0,
    one lost by both as 1 (a tie)."""
    a, b = np.asarray(values, dtype=float), np.asarray(base, dtype=float)
    fa, fb = np.isfinite(a), np.isfinite(b)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = a / b
    r = np.where(fa & fb, r, np.where(fb, np.inf, np.where(fa, 0.0, 1.0)))
    return np.where(np.isnan(r), 1.0, r)  # 0 / 0: equal scores


def bootstrap_median(x: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Median over trials of each resample (R, ...): ``x`` (n, ...), ``counts`` (R, n) from
    :func:`resample_counts`; the mean of the two middle values for an even ``n`` (as
    ``np.median``). One sort per column; a resample's median is read off the cumulative counts
    in sorted order."""
    n = x.shape[0]
    flat = x.reshape(n, -1)
    lo_rank, hi_rank = (n - 1) // 2, n // 2  # 0-based ranks of the middle values
    out = np.empty((counts.shape[0], flat.shape[1]))
    for j in range(flat.shape[1]):
        order = np.argsort(flat[:, j], kind="stable")
        xs = flat[order, j]
        cum = np.cumsum(counts[:, order], axis=1)
        i1 = np.argmax(cum > lo_rank, axis=1)
        i2 = np.argmax(cum > hi_rank, axis=1)
        with np.errstate(invalid="ignore"):
            out[:, j] = 0.5 * (xs[i1] + xs[i2])
    return out.reshape(counts.shape[0], *x.shape[1:])


@dataclass(frozen=True)
class PerTrialComparison:
    """How a method compares with a baseline trial by trial (each array (K,) over metrics):
    the median per-trial ratio with its percentile-bootstrap interval, P(improve) (the share
    of trials with a ratio below 1, ties (:data:`TIE_RTOL`) counted half) and the worst
    decile (the 90th percentile of the per-trial ratios)."""

    median: np.ndarray
    median_lo: np.ndarray
    median_hi: np.ndarray
    p_improve: np.ndarray
    worst_decile: np.ndarray


def per_trial_comparison(
    values: np.ndarray, base: np.ndarray, counts: np.ndarray, level: float
) -> PerTrialComparison:
    """:class:`PerTrialComparison` of per-trial scores ``values`` against ``base`` (n, K),
    over the resamples ``counts`` (R, n) (the same as the pooled ratio's: paired)."""
    r = trial_ratios(values, base)
    lo, hi = percentile_interval(bootstrap_median(r, counts), level)
    worst = percentiles(r, [100.0 * WORST_QUANTILE])[0]
    return PerTrialComparison(
        median=np.median(r, axis=0),
        median_lo=lo,
        median_hi=hi,
        p_improve=np.mean(np.where(np.abs(r - 1.0) <= TIE_RTOL, 0.5, r < 1.0), axis=0),
        worst_decile=worst,
    )


def median_interval_coverage(n: int, level: float) -> float:
    """Exact coverage of the population median by the percentile-bootstrap interval of the
    sample median of ``n`` trials (continuous scores; the lower median for an even ``n``).

    The bootstrap median is at most the ``j``-th order statistic ``x_(j)`` when at least
    ``k = ⌈n/2⌉`` of the ``n`` draws are: ``P = P(Bin(n, j/n) ≥ k)``. The percentile interval
    is ``[x_(jl), x_(ju)]`` with ``jl``, ``ju`` the first ``j`` where that reaches
    ``(1 − level)/2`` and ``(1 + level)/2``; it covers the median ``M`` with probability
    ``P(jl ≤ Bin(n, ½) < ju)`` (``x_(j) ≤ M`` iff at least ``j`` trials are below ``M``)."""
    from scipy import stats as sps

    a = (1.0 - level) / 2.0
    k = (n + 1) // 2
    j = np.arange(1, n + 1)
    cdf = sps.binom.sf(k - 1, n, j / n)
    jl = int(j[np.argmax(cdf >= a)])
    ju = int(j[np.argmax(cdf >= 1.0 - a)])
    return float(sps.binom.cdf(ju - 1, n, 0.5) - sps.binom.cdf(jl - 1, n, 0.5))


MEDIAN_COVERAGE_CHECKED = 500
"""Trial counts up to which :func:`min_verdict_trials` checks the coverage (beyond, the
sawtooth's minima only rise towards the nominal level)."""


@lru_cache(maxsize=16)
def min_verdict_trials(level: float) -> int:
    """Fewest trials for a verdict at ``level``: from this count on, the percentile-bootstrap
    interval of the median per-trial ratio misses the true median at most twice as often as
    it should, ``coverage ≥ level − (1 − level)`` (:func:`median_interval_coverage`; it is
    a sawtooth in ``n``, so every larger count up to :data:`MEDIAN_COVERAGE_CHECKED` is
    checked). 15 at 95 %, 11 at 90 %, 38 at 99 %."""
    floor = level - (1.0 - level)
    cov = [median_interval_coverage(n, level) for n in range(1, MEDIAN_COVERAGE_CHECKED + 1)]
    below = [n for n, c in enumerate(cov, start=1) if c < floor]
    return (max(below) + 1) if below else 1
