r"""Covariance matching: innovation-based adaptive estimation (docs/methods.md).

Mehra, "Approaches to adaptive filtering", IEEE TAC 17(5), 1972; Mohamed & Schwarz, "Adaptive
Kalman filtering for INS/GPS", Journal of Geodesy 73, 1999. Over a sliding window of the last
``W`` epochs with a measurement, the sample covariance of the innovations is matched to its
theoretical value ``H P⁻ Hᵀ + R``::

    Ĉ_v = (1/W) Σ_j ν_j ν_jᵀ                      j = the last W epochs with a measurement
    R̂   = Ĉ_v − (1/W) Σ_j H P⁻_j Hᵀ               attitude block; eigenvalues ≥ (r_floor σ_a)²
    Q̂   = K Ĉ_v Kᵀ ≈ (1/W) Σ_j (K ν)_j (K ν)_jᵀ = (1/W) Σ_j Δx_j Δx_jᵀ

``Δx_j = K_j ν_j`` is the correction the filter applied at epoch j (``FilterRecord.dx``), so the
last form needs neither K nor the innovations; it equals ``K Ĉ_v Kᵀ`` exactly when K is held
constant over the window, and approximates it while K is still changing (early in the run, in
manoeuvres). Mohamed & Schwarz derive it as the steady-state form of
``(1/W) Σ Δx Δxᵀ + P⁺_k − P⁻_k``. ``H P⁻_j Hᵀ`` of the attitude rows is the attitude block of
the filter's predicted covariance (``H_a = [I 0 0]``), read before each step. The window mean of
``H P⁻ Hᵀ`` (rather than the value at the last epoch alone) keeps ``R̂`` unbiased while ``P⁻``
still shrinks; both agree once it has settled.

Transfer alignment (:func:`run_covariance_matching`):

- **Q.** Only the diagonal of the calibration block is used, as a process-noise factor per
  term: ``κ_i = clip(Q̂_ii / (q_p0 Δt), κ_min, κ_max)`` (the ends of the action set), passed to
  the filter as a ``(B, n, 9)`` factor. The reported κ is the geometric mean over the nine terms.
- **R** (``adapt_r``). Only the attitude block is adapted. ``R̂_a`` (3×3) gets the eigenvalue floor
  ``(r_floor σ_a)²`` (σ_a the assumed sigma), then, because the filter takes an isotropic
  ``R_a = σ_a² I``, ``σ̂_a² = tr(R̂_a)/3``. The rate-row noise stays as assumed.
- **Warm-up.** Innovations enter the window only from ``t ≥ warmup_s`` (100 s), and nothing
  is adapted before the window holds ``W`` of them (κ = 1, σ_a as assumed). Without it the
  first window holds epoch 0, whose predicted attitude variance is the 60″ prior: its share of
  the window mean of ``H P⁻ Hᵀ`` (3600/W arcsec²) drives ``R̂`` negative and σ̂_a onto the floor
  (measured at 10″ true noise: one trial in eight then had a settled attitude RMS of 5″, and
  it took ~1000 s to recover).
- **Timing.** The estimate from the window that ends at epoch k drives the propagation from
  k + 1 (Q) and the update at k + 1 (R): update and propagation of an epoch run in one compiled
  call, as for Sage–Husa. Epochs without a measurement do not enter the window.
- **Safeguards.** Non-finite estimates (a diverged trial) keep the previous κ and σ_a; the
  diverged trial itself is frozen by the filter with NaN in its rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.adaptive import CovarianceMatchingConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    kappa_range,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.model import CALIB
from qkf.transfer_alignment.scenario import ScenarioData

ATT = slice(0, 3)  # attitude states, and the attitude rows of the innovation


@dataclass(frozen=True)
class WindowEstimate:
    """Covariance-matching estimates from one window, batch on axis 0."""

    c_v: np.ndarray  # (B, m, m) Ĉ_v, sample covariance of the innovations
    r: np.ndarray  # (B, m, m) R̂ = Ĉ_v − mean H P⁻ Hᵀ (no floor)
    q: np.ndarray  # (B, c, c) Q̂ = mean Δx Δxᵀ, or its diagonal (B, c)


def window_estimate(
    innov: np.ndarray, hph: np.ndarray, corr: np.ndarray, q_diagonal: bool = False
) -> WindowEstimate:
    """Covariance matching over a window (module docstring), batched over axis 0.

    ``innov`` (B, W, m) innovations ν_j; ``hph`` (B, W, m, m) the predicted ``H P⁻_j Hᵀ`` of the
    same rows; ``corr`` (B, W, c) the corrections ``Δx_j = K_j ν_j`` of the states whose Q is
    wanted. Every one of the W slots is used (the order does not matter). ``q_diagonal``:
    return only the diagonal of ``Q̂`` (B, c).
    """
    innov = np.asarray(innov, dtype=float)
    corr = np.asarray(corr, dtype=float)
    c_v = np.mean(innov[..., :, None] * innov[..., None, :], axis=1)  # Ĉ_v = (1/W) Σ ν νᵀ
    r = c_v - np.mean(np.asarray(hph, dtype=float), axis=1)  # R̂ = Ĉ_v − (1/W) Σ H P⁻ Hᵀ
    if q_diagonal:
        q = np.mean(corr * corr, axis=1)  # Q̂_ii = (1/W) Σ Δx_i²
    else:
        q = np.mean(corr[..., :, None] * corr[..., None, :], axis=1)  # Q̂ = (1/W) Σ Δx Δxᵀ
    return WindowEstimate(c_v=c_v, r=r, q=q)


def floor_eigenvalues(m: np.ndarray, floor: float) -> np.ndarray:
    """Symmetric ``m`` (…, k, k) with its eigenvalues raised to at least ``floor``."""
    m = 0.5 * (m + np.swapaxes(m, -1, -2))
    w, v = np.linalg.eigh(m)
    return (v * np.maximum(w, floor)[..., None, :]) @ np.swapaxes(v, -1, -2)


@uses_settings("covariance_matching", CovarianceMatchingConfig)
def run_covariance_matching(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Covariance-matching AKF (module docstring), batched over trials, with the settings of
    ``adaptive.covariance_matching``.

    Logs: ``kappa_terms`` (B, N, 9), the κ per calibration term in use at each epoch;
    ``sigma_a`` (B, N), the attitude sigma (rad) of each epoch's update (with ``adapt_r``).
    """
    st = cfg.adaptive.covariance_matching
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    prm = kf.params
    b, n = data.n_trials, data.n_epochs
    k_min, k_max = kappa_range(cfg)
    q_step = prm.qp0 * prm.dt  # q_p0 Δt
    r_min = (st.r_floor * prm.sigma_a) ** 2
    has_meas = np.broadcast_to(np.asarray(data.has_meas, dtype=bool), (b, n))
    w = st.window
    # ring buffers of the last W measurement epochs, per trial
    buf_nu = np.zeros((b, w, 3))
    buf_hph = np.zeros((b, w, 3, 3))
    buf_dx = np.zeros((b, w, 9))
    count = np.zeros(b, dtype=np.int64)
    rows = np.arange(b)
    kappa_t = np.ones((b, 9))
    est = np.empty((b, n, 16))
    kappa_log = np.empty((b, n, 9))
    sigma_log = np.empty((b, n))
    for k in range(n):
        kappa_log[:, k] = kappa_t
        sigma_log[:, k] = kf.sigma_a
        p_att = kf.P[:, ATT, ATT]  # H_a P⁻ H_aᵀ of this epoch
        rec = step_recording(kf, data, k, k + 1, kappa_t[:, None, :], cov)
        est[:, k] = rec.est[:, 0]
        nu = rec.innov[:, 0, ATT]
        dx = rec.dx[:, 0, CALIB]
        new = has_meas[:, k] & ~kf.diverged & np.isfinite(nu).all(axis=1)
        if data.t[k] < st.warmup_s - 1e-9 or not np.any(new):
            continue
        slot = count % w
        sel = rows[new]
        buf_nu[sel, slot[new]] = nu[new]
        buf_hph[sel, slot[new]] = p_att[new]
        buf_dx[sel, slot[new]] = dx[new]
        count[new] += 1
        full = new & (count >= w)
        if not np.any(full):
            continue
        win = window_estimate(buf_nu, buf_hph, buf_dx, q_diagonal=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            # κ_i = clip(Q̂_ii / (q_p0 Δt), κ_min, κ_max)
            kap = np.clip(win.q / q_step, k_min, k_max)
        ok_q = full & np.isfinite(kap).all(axis=1)
        kappa_t = np.where(ok_q[:, None], kap, kappa_t)
        if st.adapt_r:
            finite = full & np.isfinite(win.r).all(axis=(1, 2))
            r_hat = floor_eigenvalues(np.where(finite[:, None, None], win.r, np.eye(3)), r_min)
            r_iso = np.trace(r_hat, axis1=1, axis2=2) / 3.0  # σ̂_a² = tr(R̂_a)/3
            kf.sigma_a[:] = np.where(finite, np.sqrt(np.where(finite, r_iso, 1.0)), kf.sigma_a)
    logs: dict[str, np.ndarray] = {"kappa_terms": kappa_log}
    if st.adapt_r:
        logs["sigma_a"] = sigma_log
    kappa = np.exp(np.mean(np.log(kappa_log), axis=-1))  # geometric mean over the nine terms
    return MethodOutput(
        est=est,
        diverged=kf.diverged.copy(),
        kappa=kappa,
        logs=logs,
        cov=cov.cov,
        notes={"covariance-matching": f"window W = {w} measurement epochs"},
    )
