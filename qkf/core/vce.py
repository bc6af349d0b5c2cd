r"""Variance component estimation and robust (Huber) epoch weights (docs/least_squares.md,
"Variance components" and "Robust reweighting").

The rows of one observation group carry an a-priori sigma ``σ_row``, a variance *component*
(for example the axis) with factor ``f_c`` and a robust *epoch* (rows judged together) with
factor ``f_e``; a row's sigma in the adjustment is ``σ_row · f_c · f_e``. After a solve, with
residuals ``e`` and redundancy numbers ``r`` (``Σ r = n − u``; ``r_i = 1 − h_i``)::

    ē_i   = e_i / (σ_row f_c)                      residual normalised by the component sigma
    s_ep  = sqrt(Σ_{i∈ep} ē_i² / Σ_{i∈ep} r_i)      epoch statistic (≈ 1 for a good epoch)
    f_c  ← f_c · sqrt(Σ_{i∈c, in} ē_i² / Σ_{i∈c, in} κ_m r_i)          (Förstner/Koch)
    f_e  = (s_ep / huber)^huberPower  if s_ep > huber, else 1

The statistic of an epoch that was downweighted in the solve is evaluated as if it had full
weight (:func:`full_weight_residual`): normalising its own residual by its own (now larger)
redundancy would inflate s for a low-redundancy row and keep a good epoch downweighted for
good (observed for accelerometer epochs with r ≈ 0.07), a feedback the full-weight value does
not have.

``in``: epochs used at full weight (``f_e = 1``) whose statistic is at most ``huber``. Leaving
the rejected tail out truncates the distribution; with ``m`` rows per epoch,
``κ_m = P(χ²_{m+2} ≤ m h²) / P(χ²_m ≤ m h²)`` is the expected ``ē²/r`` of a kept row, so the
estimate stays unbiased for Gaussian data. The factors are found by a short fixed point:
first from every full-weight epoch (so a badly wrong prior cannot reject everything), then twice
with the truncation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammainc


@dataclass(frozen=True)
class RobustSettings:
    """Huber reweighting of epochs: ``huber`` (None: off), ``power`` (huberPower), and the mean
    redundancy below which an epoch cannot be judged (its factor stays 1)."""

    huber: float | None = 2.5
    power: float = 1.5
    min_redundancy: float = 1e-3


def chi2_cdf(x: np.ndarray | float, dof: np.ndarray | float) -> np.ndarray:
    """``P(χ²_dof ≤ x)`` (regularised lower incomplete gamma)."""
    return np.asarray(gammainc(np.asarray(dof, float) / 2.0, np.asarray(x, float) / 2.0))


def truncation_factor(rows: np.ndarray | int, huber: float | None) -> np.ndarray:
    """``κ_m = P(χ²_{m+2} ≤ m h²) / P(χ²_m ≤ m h²)``: mean square of one unit-normal component
    of an m-vector kept only when its mean square is at most ``h²`` (1 without truncation)."""
    m = np.asarray(rows, dtype=float)
    if huber is None or not np.isfinite(huber):
        return np.ones_like(m)
    values, inverse = np.unique(m, return_inverse=True)  # few distinct row counts
    c = values * huber**2
    return (chi2_cdf(c, values + 2.0) / chi2_cdf(c, values))[inverse].reshape(m.shape)


@dataclass(frozen=True)
class GroupEstimate:
    """Result of :func:`estimate_group`: new factors and the diagnostics behind them."""

    component_sigma: np.ndarray  # f_c (n_components,)
    epoch_sigma: np.ndarray  # f_e (n_epochs,)
    epoch_statistic: np.ndarray  # s_ep with the new f_c (NaN for epochs without rows)
    redundancy_per_component: np.ndarray  # Σ r over the kept rows of each component


def full_weight_residual(
    residual: np.ndarray, redundancy: np.ndarray, factor: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Residual and redundancy a row would have at full weight, from those of a solve in which
    its sigma was scaled by ``factor`` (leave-one-out identity, exact for one row)::

        r₁ = r_f / (r_f + f² (1 − r_f)),      e₁ = e_f · r₁ / r_f

    (``e = r · ẽ`` with ẽ the residual against the prediction from all other rows, whose
    variance ``σ² + v`` does not depend on the row's own weight). Rows at full weight are
    returned unchanged.
    """
    f2 = np.asarray(factor, dtype=float) ** 2
    r = np.clip(redundancy, 0.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        r1 = np.where(f2 == 1.0, r, r / (r + f2 * (1.0 - r)))
        e1 = np.where(f2 == 1.0, residual, residual * np.where(r > 0.0, r1 / r, 0.0))
    return e1, np.nan_to_num(r1)


def _epoch_sums(values: np.ndarray, epoch: np.ndarray, n_epochs: int) -> np.ndarray:
    return np.bincount(epoch, weights=values, minlength=n_epochs)


def estimate_group(
    residual: np.ndarray,
    sigma: np.ndarray,
    component: np.ndarray,
    epoch: np.ndarray,
    redundancy: np.ndarray,
    component_sigma: np.ndarray,
    epoch_sigma: np.ndarray,
    estimate_components: bool = True,
    robust: RobustSettings | None = None,
) -> GroupEstimate:
    """One variance-component and robust step for one observation group (see module docstring).

    ``residual`` e, ``sigma`` σ_row, ``redundancy`` r per row (same units as e for e and σ);
    ``component``/``epoch`` integer labels per row; ``component_sigma``/``epoch_sigma`` the
    factors used in the solve that produced ``residual``.
    """
    robust = robust or RobustSettings(huber=None)
    n_epochs = epoch_sigma.size
    n_comp = component_sigma.size
    rows_per_epoch = np.bincount(epoch, minlength=n_epochs).astype(float)
    e_full, r_full = full_weight_residual(residual, redundancy, epoch_sigma[epoch])
    r_epoch = _epoch_sums(r_full, epoch, n_epochs)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_r = r_epoch / rows_per_epoch
    judged = (rows_per_epoch > 0) & (mean_r > robust.min_redundancy)
    full_weight = (epoch_sigma == 1.0) & judged
    kappa_epoch = truncation_factor(np.maximum(rows_per_epoch, 1.0), robust.huber)
    huber = robust.huber if robust.huber is not None else np.inf

    def statistic(f_c: np.ndarray) -> np.ndarray:
        e2 = (e_full / (sigma * f_c[component])) ** 2  # ē² at full weight
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.sqrt(_epoch_sums(e2, epoch, n_epochs) / r_epoch)

    def components(f_c: np.ndarray, kept: np.ndarray, kappa: np.ndarray) -> np.ndarray:
        row_kept = kept[epoch]
        e2 = (residual / (sigma * f_c[component])) ** 2
        num = np.bincount(component[row_kept], weights=e2[row_kept], minlength=n_comp)
        den = np.bincount(
            component[row_kept],
            weights=(redundancy * kappa[epoch])[row_kept],
            minlength=n_comp,
        )
        ok = (den > 0) & (num > 0)
        out = f_c.copy()
        out[ok] = f_c[ok] * np.sqrt(num[ok] / den[ok])
        return out

    f_c = np.asarray(component_sigma, dtype=float).copy()
    kept = full_weight
    if estimate_components:
        f_c = components(f_c, full_weight, np.ones(n_epochs))
        if np.isfinite(huber):
            for _ in range(2):
                kept = full_weight & (statistic(f_c) <= huber)
                f_c = components(np.asarray(component_sigma, float), kept, kappa_epoch)
    s = statistic(f_c)
    if np.isfinite(huber):
        kept = full_weight & (s <= huber)
    new_epoch = np.ones(n_epochs)
    if np.isfinite(huber):
        outlier = judged & (s > huber)
        new_epoch[outlier] = (s[outlier] / huber) ** robust.power
    r_comp = np.bincount(component[kept[epoch]], weights=redundancy[kept[epoch]], minlength=n_comp)
    return GroupEstimate(f_c, new_epoch, np.where(rows_per_epoch > 0, s, np.nan), r_comp)
