r"""Strong-tracking (fading-memory) filter: one adaptive fading factor λ ≥ 1 (docs/methods.md).

The strong tracking filter of Zhou & Frank inflates the propagated covariance whenever the
innovations are larger than the filter expects. For the prediction into epoch ``k``::

    ν_k  = z_k − H x̂⁻_k                                    innovation
    V_k  = (ρ V_{k−1} + ν_k ν_kᵀ) / (1 + ρ),  V_0 = ν_0 ν_0ᵀ  its covariance, forgetting ρ
    N_k  = V_k − β R_k − H Q_{k−1} Hᵀ                        β ≥ 1: softening factor
    M_k  = H Φ_{k−1} P⁺_{k−1} Φ_{k−1}ᵀ Hᵀ
    λ_k  = max(1, tr N_k / tr M_k)                           fading factor
    P⁻_k = λ_k Φ_{k−1} P⁺_{k−1} Φ_{k−1}ᵀ + Q_{k−1}            faded prediction

then the ordinary update at ``k`` with ``P⁻_k``. :func:`strong_tracking_step` is this cycle for
a linear model, batched over leading axes.

**On the transfer-alignment filter** (:func:`run_fading`). The compiled filter does the update
at ``k`` and the propagation to ``k + 1`` in one call and cannot scale ``Φ P Φᵀ`` itself, so
each epoch:

1. before the call for epoch ``k``, the attitude innovation ``ν_k = Log(Ĉ⁻ᵀ C_ADS,k)`` is formed
   from the filter's predicted attitude (exactly what the filter will compute, bit for bit: the
   compiled model's :func:`~qkf.transfer_alignment.model_compiled.attitude_innovation`);
2. ``λ_k`` from the *attitude rows* only (``H = [I 0 0]``, ``R = σ_a² I``): the attitude is
   measured in both matching schemes, and mixing the traces of rad² and (rad/s)² rows would
   weigh them arbitrarily. ``H Q Hᵀ`` is generalised to everything in ``P⁻`` that is not
   ``Φ P⁺ Φᵀ`` (``Q_d`` plus the correlated rate-noise terms of the filter), i.e.
   ``H (P⁻_k − Φ P⁺ Φᵀ) Hᵀ``: without rate matching that is ``H Q Hᵀ`` exactly;
3. the fading is applied to the predicted covariance as
   ``P⁻_k ← P⁻_k + (λ_k − 1) Φ_{k−1} P⁺_{k−1} Φ_{k−1}ᵀ``, which equals ``λ Φ P⁺ Φᵀ + Q`` (plus the
   unchanged correlation terms). With λ ≥ 1 it only adds a positive semi-definite term, so
   ``P⁻`` stays symmetric positive definite. ``P⁺_{k−1}`` is the recorded posterior covariance
   of the previous call and ``Φ_{k−1}`` the exact transition at that call's ``ω̂`` and
   ``A = (I + K(p̂))⁻¹`` (:func:`transition`: the compiled model's
   :func:`~qkf.transfer_alignment.model_compiled.transition_matrix`, the kernel's arithmetic);
4. the call for epoch ``k`` (update with the faded ``P⁻_k``, propagation with κ = 1).

``V`` starts at the first epoch where λ is evaluated (epoch 1: the innovation of epoch 0 is zero
by construction, ``Ĉ_0 = C_ADS,0``). Epochs without a measurement keep ``V`` and have λ = 1.

**Safeguards.** ``λ ≤ lambda_max`` bounds one inflation, and ``λ ≤ λ_cap`` with
``λ_cap = 1 + min_i max(P_0,ii − P⁻_ii, 0) / (Φ P⁺ Φᵀ)_ii`` (:func:`prior_cap`): the fading never
raises a variance above the prior ``P_0``. Without the cap inflations compound (λ is applied at
every epoch while ``V`` stays large) and the filter diverged in 4 of 4 ``paper`` trials with
β = 1 or 2 before 310 s.

**Defaults** (``forgetting`` ρ = 0.95, ``softening`` β = 4, ``lambda_max`` = 10). ρ = 0.95 is
the textbook value: ``V`` has a memory of about three epochs. Once the filter has converged the
attitude innovation is dominated by the ADS noise (``tr R / tr M ≈ 200``), so ``tr N / tr M``
is a small difference of noisy numbers over a small one, and λ > 1 fires on noise alone: in
``paper`` at 42 % of the epochs with β = 1, 4 % with β = 2, 0.3 % with β = 3, 0.03 % with
β = 4. β = 4 keeps false alarms rare; the price is that only large mismatches fire it.
ρ > 1 is accepted (the same formula, a memory of about 1 + ρ epochs) but is not textbook.

**κ reported.** The fading scales the whole ``Φ P⁺ Φᵀ`` (attitude, bias and calibration); its
effect on the calibration block (``Φ`` is the identity there) equals a process-noise factor per
term ``κ_i = 1 + (λ − 1) P⁺_ii / (q_p0 Δt)``. The reported κ is the geometric mean over the nine
terms, clipped to the action range; the unclipped values are logged (``kappa_equiv``), with λ
(``lambda``).

Units SI: rad, rad/s, s; ``V``, ``R``, ``M``, ``N`` in rad² for the attitude rows.
"""

from __future__ import annotations

import numpy as np

from qkf.transfer_alignment.adaptive import FadingConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    kappa_range,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder
from qkf.transfer_alignment.model import CALIB, THETA
from qkf.transfer_alignment.model_compiled import attitude_innovation
from qkf.transfer_alignment.model_compiled import transition_matrix as transition
from qkf.transfer_alignment.scenario import ScenarioData

# ---- generic strong-tracking algebra (numpy, batched over leading axes) ------------------------


def forget_innovation_covariance(
    v_prev: np.ndarray | None, nu: np.ndarray, rho: float
) -> np.ndarray:
    """``V_k = (ρ V_{k−1} + ν νᵀ)/(1 + ρ)``; ``V_0 = ν νᵀ`` when ``v_prev`` is None.

    ``nu`` (…, m) → (…, m, m)."""
    outer = nu[..., :, None] * nu[..., None, :]  # ν νᵀ
    if v_prev is None:
        return outer
    return (rho * v_prev + outer) / (1.0 + rho)


def fading_factor(
    v: np.ndarray, r: np.ndarray, hqh: np.ndarray, m: np.ndarray, beta: float
) -> np.ndarray:
    """``λ = max(1, tr N / tr M)``, ``N = V − β R − H Q Hᵀ``; all (…, m, m) → (…)."""
    tr_n = np.trace(v - beta * r - hqh, axis1=-2, axis2=-1)  # tr N
    tr_m = np.trace(m, axis1=-2, axis2=-1)  # tr M = tr(H Φ P Φᵀ Hᵀ)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.maximum(1.0, tr_n / tr_m)


def strong_tracking_step(
    x: np.ndarray,
    p: np.ndarray,
    v_prev: np.ndarray | None,
    z: np.ndarray,
    phi: np.ndarray,
    q: np.ndarray,
    h: np.ndarray,
    r: np.ndarray,
    rho: float,
    beta: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One strong-tracking cycle of a linear model from the posterior at ``k − 1`` to ``k``.

    ``x`` (…, n), ``p`` (…, n, n) posterior at k − 1; ``z`` (…, m) measurement at k; ``phi``,
    ``q`` (n, n) or batched; ``h`` (m, n); ``r`` (m, m). Returns the posterior ``x``, ``P`` at
    ``k``, ``V_k`` and ``λ_k``.
    """
    ht = np.swapaxes(h, -1, -2)
    x_pred = np.einsum("...ij,...j->...i", phi, x)  # x̂⁻ = Φ x̂⁺
    nu = z - np.einsum("...ij,...j->...i", h, x_pred)  # ν = z − H x̂⁻
    v = forget_innovation_covariance(v_prev, nu, rho)
    php = phi @ p @ np.swapaxes(phi, -1, -2)  # Φ P⁺ Φᵀ
    lam = fading_factor(v, r, h @ q @ ht, h @ php @ ht, beta)
    p_pred = lam[..., None, None] * php + q  # P⁻ = λ Φ P⁺ Φᵀ + Q
    s = h @ p_pred @ ht + r  # S = H P⁻ Hᵀ + R
    gain = p_pred @ ht @ np.linalg.inv(s)  # K = P⁻ Hᵀ S⁻¹
    x_post = x_pred + np.einsum("...ij,...j->...i", gain, nu)
    i_kh = np.eye(p.shape[-1]) - gain @ h
    p_post = i_kh @ p_pred @ np.swapaxes(i_kh, -1, -2) + gain @ r @ np.swapaxes(gain, -1, -2)
    return x_post, p_post, v, lam


# ---- the transfer-alignment filter --------------------------------------------------------------


def prior_cap(p_pred: np.ndarray, php: np.ndarray, p0_var: np.ndarray) -> np.ndarray:
    """The largest λ (…) for which no diagonal element of ``P⁻ + (λ − 1) Φ P⁺ Φᵀ`` exceeds the
    prior variance ``P_0,ii`` (or its current value, if that is larger already):
    ``λ_cap = 1 + min_i max(P_0,ii − P⁻_ii, 0) / (Φ P⁺ Φᵀ)_ii``."""
    d_pred = np.diagonal(p_pred, axis1=-2, axis2=-1)
    d_php = np.diagonal(php, axis1=-2, axis2=-1)
    room = np.maximum(p0_var - d_pred, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(d_php > 0.0, room / d_php, np.inf)
    return 1.0 + np.min(ratio, axis=-1)


@uses_settings("fading", FadingConfig)
def run_fading(cfg: Config, data: ScenarioData) -> MethodOutput:
    """The ``fading`` method: :func:`fading_filter` with the config's settings
    (``adaptive.fading``)."""
    return fading_filter(cfg, data, cfg.adaptive.fading)


def fading_filter(cfg: Config, data: ScenarioData, prm: FadingConfig) -> MethodOutput:
    """Strong-tracking filter, batched over trials, stepping one epoch at a time, with the
    settings ``prm`` (``FadingConfig``: ``forgetting`` ρ, ``softening`` β, ``lambda_max``).

    Logs λ per epoch (``lambda``, (B, N)) and the unclipped equivalent calibration κ
    (``kappa_equiv``, (B, N))."""
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    b, n = data.n_trials, data.n_epochs
    dt, qp0 = cfg.scenario.dt_s, cfg.filter.qp0
    est = np.empty((b, n, 16))
    lam_log = np.ones((b, n))
    kappa_eq = np.ones((b, n))
    p0_var = kf.P[0].diagonal().copy()  # prior variances P_0,ii (15,)
    v: np.ndarray | None = None  # V_k per trial (B, 3, 3)
    php: np.ndarray | None = None  # Φ_{k−1} P⁺_{k−1} Φ_{k−1}ᵀ (B, 15, 15)
    var_post: np.ndarray | None = None  # diag P⁺_{k−1} of the calibration block (B, 9)
    for k in range(n):
        # per-trial mask: recorded runs may update on different epochs in each trial
        meas_k = np.broadcast_to(data.has_meas[..., k], (b,))
        if php is not None and var_post is not None and meas_k.any():
            nu = attitude_innovation(kf.q_hat, data.ads_q[:, k])  # ν_k from Ĉ⁻_k
            v = forget_innovation_covariance(v, nu, prm.forgetting)
            p_pred = kf.P
            r_a = (kf.sigma_a**2)[:, None, None] * np.eye(3)  # R_a = σ_a² I
            other = p_pred[:, THETA, THETA] - php[:, THETA, THETA]  # H (P⁻ − Φ P⁺ Φᵀ) Hᵀ
            lam = fading_factor(v, r_a, other, php[:, THETA, THETA], prm.softening)
            lam = np.minimum(lam, prm.lambda_max)
            lam = np.minimum(lam, prior_cap(p_pred, php, p0_var))
            ok = np.isfinite(lam) & ~kf.diverged & meas_k
            lam = np.where(ok, lam, 1.0)
            # P⁻ ← P⁻ + (λ − 1) Φ P⁺ Φᵀ  (= λ Φ P⁺ Φᵀ + Q); rows with λ = 1 unchanged
            faded = np.where(ok[:, None, None], p_pred + (lam - 1.0)[:, None, None] * php, p_pred)
            kf.P = faded
            lam_log[:, k] = lam
            # effect on the calibration block, as a κ per term: 1 + (λ − 1) P⁺_ii / (q_p0 Δt)
            kap_terms = 1.0 + (lam - 1.0)[:, None] * var_post / (qp0 * dt)
            kappa_eq[:, k] = np.exp(np.mean(np.log(kap_terms), axis=-1))
        rec = kf.step_data(data, k, k + 1, kappa=1.0, record_cov=True)
        est[:, k] = rec.est[:, 0]
        assert rec.cov is not None
        p_post = rec.cov[:, 0]
        cov.take(k, p_post)
        rate, p_hat = rec.rate[:, 0], kf.p_hat
        ok = np.isfinite(rate).all(axis=1) & np.isfinite(p_hat).all(axis=1)
        phi = transition(np.where(ok[:, None], rate, 0.0), np.where(ok[:, None], p_hat, 0.0), dt)
        php = phi @ np.where(ok[:, None, None], p_post, 0.0) @ np.swapaxes(phi, -1, -2)
        php = 0.5 * (php + np.swapaxes(php, -1, -2))  # Φ P⁺ Φᵀ, symmetric
        var_post = np.where(ok[:, None], rec.var[:, 0, CALIB], 0.0)
    lo, hi = kappa_range(cfg)
    kappa = np.clip(np.where(np.isfinite(kappa_eq), kappa_eq, 1.0), lo, hi)
    notes = {
        "fading": (
            f"ρ = {prm.forgetting:g}, β = {prm.softening:g}; λ > 1 at "
            f"{np.mean(lam_log > 1.0):.1%} of epochs, max {np.max(lam_log):.3g}"
        )
    }
    return MethodOutput(
        est=est,
        diverged=kf.diverged.copy(),
        kappa=kappa,
        logs={"lambda": lam_log, "kappa_equiv": kappa_eq},
        cov=cov.cov,
        notes=notes,
    )
