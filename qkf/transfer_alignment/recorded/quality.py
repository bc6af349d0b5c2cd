r"""Truth-free quality of a filter on recorded data (docs/recorded_data.md, "Without truth").

Without the truth, a filter is judged by its innovations against the model it assumes:

- **NIS band.** For a consistent filter the normalised innovation squared of a block of ``m``
  rows, ``ε_k = ν_kᵀ S_k⁻¹ ν_k``, is ``χ²(m)``. Per epoch it lies inside the two-sided band
  ``[χ²_m((1−L)/2), χ²_m((1+L)/2)]`` with probability ``L`` (0.95), and its mean over ``n``
  independent epochs is ``χ²(m n)/n``. Reported: the fraction of settled epochs inside the band
  and the mean ``ε̄/m`` (1 when consistent) with its own ``FLAG_LEVEL`` band.
- **Whiteness.** The innovations of a filter whose model fits are white. Per component ``j`` of
  the innovation and lag ``l`` (in measurement epochs) the normalised autocorrelation
  ``ρ_j(l) = Σ_k ν̄_{j,k} ν̄_{j,k+l} / Σ_k ν̄_{j,k}²`` of the mean-removed sequence ``ν̄`` is
  about ``N(0, 1/n)`` for white innovations; reported: ``max |ρ|`` over components and lags
  ``1 … LAGS`` and the fraction of them outside ``±z_{(1+L)/2}/√n``.

A measure is *flagged* (summary.md) when the filter's own model is refuted by it: the fraction
inside the band is below ``MIN_IN_BAND`` (0.90), the mean lies outside its ``FLAG_LEVEL`` band,
or more than ``MAX_CORRELATED`` of the autocorrelations lie outside theirs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

LAGS = 10
"""Autocorrelation lags of the whiteness check, in measurement epochs."""
MIN_IN_BAND = 0.90
"""Fewer settled epochs inside the NIS band than this is flagged (a consistent filter: 0.95)."""
FLAG_LEVEL = 0.999
"""Two-sided level of the band of the mean NIS (a mean outside it is flagged)."""
MAX_CORRELATED = 0.25
"""More autocorrelations outside their band than this fraction is flagged (white: 0.05)."""

QUALITY_COLUMNS: tuple[str, ...] = (
    "method",
    "trial",
    "block",
    "epochs",
    "nis_mean",
    "nis_mean_lo",
    "nis_mean_hi",
    "in_band",
    "whiteness_max",
    "whiteness_outside",
    "flag",
)
"""quality.csv: one row per method, trial and innovation block (attitude, rate)."""


@dataclass(frozen=True)
class BlockQuality:
    """NIS and whiteness of one innovation block of one trial."""

    block: str  # "attitude" | "rate"
    epochs: int  # settled epochs with this update
    nis_mean: float  # mean NIS / dof (1 when consistent); NaN without epochs
    nis_mean_lo: float  # FLAG_LEVEL band of nis_mean
    nis_mean_hi: float
    in_band: float  # fraction of the epochs whose NIS lies inside the level band
    whiteness_max: float  # max |ρ| over components and lags 1..LAGS
    whiteness_outside: float  # fraction of (component, lag) outside ±z/√n
    flags: tuple[str, ...]

    def row(self, method: str, trial: int) -> list[object]:
        return [
            method,
            trial,
            self.block,
            self.epochs,
            self.nis_mean,
            self.nis_mean_lo,
            self.nis_mean_hi,
            self.in_band,
            self.whiteness_max,
            self.whiteness_outside,
            "; ".join(self.flags),
        ]


def nis_band(dof: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided ``level`` band of one ``χ²(dof)`` NIS value."""
    lo, hi = stats.chi2.ppf([(1 - level) / 2, (1 + level) / 2], dof)
    return float(lo), float(hi)


def mean_band(dof: int, n: int, level: float = FLAG_LEVEL) -> tuple[float, float]:
    """Two-sided ``level`` band of the mean of ``n`` independent ``χ²(dof)`` values, divided by
    ``dof``: ``χ²(dof·n) / (dof·n)``."""
    lo, hi = stats.chi2.ppf([(1 - level) / 2, (1 + level) / 2], dof * n)
    return float(lo) / (dof * n), float(hi) / (dof * n)


def autocorrelation(x: np.ndarray, lags: int = LAGS) -> np.ndarray:
    """Normalised autocorrelation ``ρ(l)``, ``l = 1 … lags``, of each column of ``x`` (n, m)
    after removing its mean: (lags, m). NaN where ``n ≤ lags`` or a column is constant."""
    n, m = x.shape
    out = np.full((lags, m), np.nan)
    if n <= lags:
        return out
    xc = x - x.mean(axis=0)
    denom = np.sum(xc * xc, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        for lag in range(1, lags + 1):
            out[lag - 1] = np.sum(xc[:-lag] * xc[lag:], axis=0) / denom
    return out


def block_quality(
    block: str,
    nis: np.ndarray,
    innov: np.ndarray | None,
    use: np.ndarray,
    dof: int = 3,
    level: float = 0.95,
) -> BlockQuality:
    """Quality of one block: ``nis`` (N,) NIS per epoch (NaN: no update), ``innov`` (N, dof)
    its innovations (SI; None: whiteness not computed), ``use`` (N,) the epochs judged."""
    ok = use & np.isfinite(nis)
    n = int(np.count_nonzero(ok))
    if n == 0:
        nan = float("nan")
        return BlockQuality(block, 0, nan, nan, nan, nan, nan, nan, ())
    vals = nis[ok]
    lo, hi = nis_band(dof, level)
    in_band = float(np.mean((vals >= lo) & (vals <= hi)))
    mean = float(np.mean(vals) / dof)
    m_lo, m_hi = mean_band(dof, n)
    w_max = w_out = float("nan")
    if innov is not None:
        seq = innov[ok]
        seq = seq[np.isfinite(seq).all(axis=1)]
        rho = autocorrelation(seq)
        if np.isfinite(rho).any():
            bound = stats.norm.ppf((1 + level) / 2) / np.sqrt(seq.shape[0])
            w_max = float(np.nanmax(np.abs(rho)))
            w_out = float(np.mean(np.abs(rho[np.isfinite(rho)]) > bound))
    flags = []
    if in_band < MIN_IN_BAND:
        flags.append(
            f"{block} NIS inside its {level:.0%} band on {in_band:.1%} of {n} epochs "
            f"(consistent: {level:.0%}; flagged below {MIN_IN_BAND:.0%})"
        )
    if not m_lo <= mean <= m_hi:
        flags.append(
            f"{block} mean NIS/{dof} = {mean:.3g}, outside [{m_lo:.3g}, {m_hi:.3g}] "
            f"({FLAG_LEVEL:.1%} band): the assumed noise is too "
            f"{'small' if mean > m_hi else 'large'} for these data"
        )
    if np.isfinite(w_out) and w_out > MAX_CORRELATED:
        flags.append(
            f"{block} innovations correlated: {w_out:.0%} of the autocorrelations at lags "
            f"1–{LAGS} outside their {level:.0%} band (max |ρ| = {w_max:.2f})"
        )
    return BlockQuality(block, n, mean, m_lo, m_hi, in_band, w_max, w_out, tuple(flags))
