r"""Variational-Bayes adaptive Kalman filter for inaccurate Q and R (docs/methods.md).

Huang, Zhang, Wu, Li, Chambers, "A Novel Adaptive Kalman Filter With Inaccurate Process and
Measurement Noise Covariance Matrices", IEEE TAC 63(2):594–601, 2018, Algorithm 1. The
predicted covariance ``P⁻`` and the measurement noise ``R`` get inverse-Wishart priors and are
inferred together with the state by fixed-point (mean-field) iterations at every measurement::

    P̃⁻ = Φ P⁺_{k−1} Φᵀ + Q̃                          nominal prediction (the filter's own, κ = 1)
    t̂⁻ = n + τ + 1,   T̂⁻ = τ P̃⁻                     prior of P⁻:  IW(t̂⁻, T̂⁻), mean P̃⁻
    û⁻ = ρ (û_{k−1} − m − 1) + m + 1,  Û⁻ = ρ Û_{k−1}  prior of R:   spread by the forgetting ρ
    x̂⁽⁰⁾ = x̂⁻,  P⁽⁰⁾ = P̃⁻
    for i = 0 … N − 1:
        A = (x̂⁽ⁱ⁾ − x̂⁻)(x̂⁽ⁱ⁾ − x̂⁻)ᵀ + P⁽ⁱ⁾,         t̂ = t̂⁻ + 1,  T̂ = T̂⁻ + A
        B = (z − H x̂⁽ⁱ⁾)(z − H x̂⁽ⁱ⁾)ᵀ + H P⁽ⁱ⁾ Hᵀ,    û = û⁻ + 1,  Û = Û⁻ + B
        P̂⁻ = E[P⁻⁻¹]⁻¹ = T̂ / (t̂ − n − 1) = (τ P̃⁻ + A) / (τ + 1)
        R̂  = E[R⁻¹]⁻¹  = Û / (û − m − 1)
        K = P̂⁻ Hᵀ (H P̂⁻ Hᵀ + R̂)⁻¹,  x̂⁽ⁱ⁺¹⁾ = x̂⁻ + K (z − H x̂⁻)
        P⁽ⁱ⁺¹⁾ = (I − K H) P̂⁻ (I − K H)ᵀ + K R̂ Kᵀ     (Joseph form)
    x̂⁺ = x̂⁽ᴺ⁾,  P⁺ = P⁽ᴺ⁾,  û_k = û,  Û_k = Û       (Û from the iterate N − 1, as in the paper)

Defaults as in the paper's simulation: ``N = 10``, ``τ = 3``, ``ρ = 1 − e⁻⁴`` (a memory of
``1/(1 − ρ) ≈ 55`` measurements for R). The R prior starts at ``û_0 = m + 1 + τ_R``,
``Û_0 = τ_R R̃`` (mean ``R̃``, the assumed noise; ``τ_R = 3``).

Expectations. The paper writes ``E[P⁻¹] = (t̂ − n − 1) T̂⁻¹`` (its IW convention; the authors'
code does the same), which makes ``P̂⁻`` the weighted average ``(τ P̃⁻ + A)/(τ + 1)`` of its
Eq. (50). The textbook inverse-Wishart moment ``E[P⁻¹] = t̂ T̂⁻¹`` would give
``(τ P̃⁻ + A)/(n + τ + 2)``: for the 15 states here a shrink of ``P⁻`` by 5–6× per epoch in
every direction the measurement does not see (``τ/(n + τ + 1) = 3/19`` at the fixed point), so
the covariance of the unobserved terms would collapse within a few epochs.
This module follows the paper.

Transfer alignment (:func:`run_vbakf`). The error state is reset after every update, so
``x̂⁻ = 0`` and ``z − H x̂⁻`` is the innovation ``ν``. At each epoch with a measurement:

1. ``P̃⁻`` is the compiled filter's predicted covariance (κ = 1, with the correlated-noise
   terms of the rate matching), ``H``, ``R`` and ``ν`` its measurement model
   (:mod:`qkf.transfer_alignment.model`) at the current estimate;
2. the N iterations run in the filter's scaled units (``P̃ = D⁻¹ P D⁻¹``, measurement rows
   divided by their nominal sigmas);
3. the filter is handed ``P̂⁻`` (``kf.P``) and the adapted attitude sigma (``kf.sigma_a``) of
   the last iteration and runs its own update (the same Joseph update, in scaled units), the
   reset and the propagation with the nominal ``Q̃``. Its posterior equals the VB ``P⁽ᴺ⁾``
   to rounding (a test checks it).

Steps 1–2 and the hand-over run compiled, one call per measurement epoch for all trials
(:func:`~qkf.transfer_alignment.methods.vbakf_compiled.vb_epoch`, the equations above, Joseph
form multiplied out, trials in parallel). Their numpy reference is ``tests/vbakf_numpy.py``
(``vb_step`` for any state size, ``scaled_measurement``): the tests check the compiled step and
epoch against it (to 1e-12). The compiled rate matrix ``A`` is the filter's own (adjugate, not
``np.linalg.inv``); a measurement model that cannot be formed (``I + K(p̂)`` singular) or whose
``S`` has a non-positive Cholesky pivot ends the trial like a non-finite one.

Departures, all forced by the filter's measurement model: only the attitude block of ``R`` is
adapted (``m = 3`` in the IW of R; the rate-row noise ``R_r`` stays as assumed, its cross terms
with the attitude rows zero), and the filter takes an isotropic ``R_a = σ_a² I``, so the
update uses ``σ̂_a² = tr(R̂_a)/3`` (the IW state ``Û`` itself keeps the full 3×3 matrix).
Epochs without a measurement (gaps) are plain predictions: no iteration, no forgetting of R.

κ. VB does not choose a process-noise density; it replaces ``P̃⁻`` by ``P̂⁻``. The reported κ is
the effective inflation of the calibration block::

    κ_i = clip( 1 + (P̂⁻ − P̃⁻)_ii / (q_p0 Δt),  κ_min, κ_max ),   i = calibration terms
    κ   = exp( mean_i log κ_i )                           (geometric mean over the nine)

since ``(P̃⁻ − Φ P⁺ Φᵀ)_ii = q_p0 Δt`` on that block (Φ is the identity there and the
correlation terms do not touch it). ``P̂⁻ − P̃⁻ = (A − P̃⁻)/(τ + 1)`` is often far outside the
action range (negative when the update shrinks a term more than the innovation supports), so
the clip is active much of the time; ``logs["kappa_terms"]`` has the nine clipped values.

Known behaviour: P⁻ or R? One innovation cannot tell a too-small ``P⁻`` from a too-small
``R``, and here ``P̃⁻`` has a long memory (the attitude, bias and calibration process noise is
tiny, so ``P̃⁻_{k+1} ≈ P⁺_k``) while R forgets with ``ρ``. With the filter assuming 3″ and the
ADS at 10″ (``paper``, 30 trials of 3600 s), the iterations settle in one of two fixed points:
in 14 trials ``σ̂_a → 10″`` and the settled attitude RMS is 0.79 × the KF's; in 16 the excess
innovation is put into ``P̂⁻`` (gain → 1, ``σ̂_a → 1.9″``, effective κ ≈ 40) and the filter
follows the ADS (9.6″). Fewer iterations (N = 3), a tighter prior (τ = 30) or R alone
(``adapt_p: false``) all avoid the second mode (0.78–0.79 × KF); the defaults stay the paper's.

Safeguards: ``P̂⁻`` is a positive combination of positive semi-definite matrices and the update
is Joseph-form, so both stay symmetric positive semi-definite (symmetrised after each
product); ``Û`` stays positive definite because ``B ⪰ H P Hᵀ``. A trial whose numbers go
non-finite is flagged diverged and frozen by the filter (NaN in its rows); inactive rows
(diverged, or no measurement) are not iterated and keep ``P̃⁻``, and each trial's compiled step
reads and writes only its own rows, so one trial never affects another.
"""

from __future__ import annotations

import math

import numpy as np

from qkf.transfer_alignment import model
from qkf.transfer_alignment.adaptive import VbakfConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    MethodOutput,
    kappa_range,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.methods.vbakf_compiled import vb_epoch_loops
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import ScenarioData


def r_prior(r_nominal: np.ndarray, dof: float) -> tuple[np.ndarray, np.ndarray]:
    """Initial IW state of R with mean ``r_nominal`` (…, a, a): ``û_0 = a + 1 + τ_R``,
    ``Û_0 = τ_R R̃``."""
    r_nominal = np.asarray(r_nominal, dtype=float)
    a = r_nominal.shape[-1]
    u0 = np.full(r_nominal.shape[:-2], a + 1.0 + dof)  # û_0 = m + 1 + τ_R
    return u0, dof * r_nominal  # Û_0 = τ_R R̃  (E[R] = Û/(û − m − 1) = R̃)


def row_scales(prm: FilterParams) -> np.ndarray:
    """The filter's measurement row scales ``e`` (m,): ``e_a = σ_a`` (rad, the assumed, not the
    adapted sigma) and, with rate matching, ``e_r = √(σ_r² + σ_v²/Δt)`` (rad/s)."""
    e = np.full(3, prm.sigma_a)
    if prm.use_rate:
        e = np.concatenate([e, np.full(3, math.sqrt(prm.sigma_r**2 + prm.sigma_v**2 / prm.dt))])
    return e


@uses_settings("vbakf", VbakfConfig)
def run_vbakf(cfg: Config, data: ScenarioData) -> MethodOutput:
    """VBAKF (module docstring) on every trial, batched over trials, with the settings of
    ``adaptive.vbakf``.

    Logs: ``kappa_terms`` (B, N, 9), the clipped effective κ per calibration term;
    ``sigma_a`` (B, N), the attitude sigma (rad) the update of each epoch used;
    ``r_dof`` (B, N), ``û`` after each epoch.
    """
    st = cfg.adaptive.vbakf
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    prm = kf.params
    b, n = data.n_trials, data.n_epochs
    k_min, k_max = kappa_range(cfg)
    d = prm.p0_sigma
    dd = np.outer(d, d)
    q_step = prm.qp0 * prm.dt / d[model.CALIB] ** 2  # q_p0 Δt in scaled units, per calibration term
    has_meas = np.broadcast_to(np.asarray(data.has_meas, dtype=bool), (b, n))
    # IW state of R_a in scaled units (R̃_a = I for the assumed σ_a)
    u, u_scale = r_prior(np.broadcast_to(np.eye(3), (b, 3, 3)), st.r_prior_dof)
    u_scale = u_scale.copy()
    est = np.empty((b, n, 16))
    kappa_log = np.ones((b, n, 9))
    sigma_log = np.empty((b, n))
    dof_log = np.empty((b, n))
    # the compiled epoch (vbakf_compiled.vb_epoch): model constants, settings, outputs
    e = row_scales(prm)
    consts = np.array([prm.dt, prm.sigma_a, prm.sigma_r, prm.sigma_v], dtype=float)
    settings = np.array([st.tau, st.forgetting, k_min, k_max, st.iterations], dtype=float)
    flags = np.array([st.adapt_p, st.adapt_r], dtype=bool)
    gyro = np.ascontiguousarray(data.gyro, dtype=float)
    ads_q = np.ascontiguousarray(data.ads_q, dtype=float)
    ads_rate = np.ascontiguousarray(data.ads_rate, dtype=float)
    d = np.ascontiguousarray(d, dtype=float)
    q_step = np.ascontiguousarray(q_step, dtype=float)
    p_out = np.empty((b, 15, 15))
    kap = np.empty((b, 9))
    bad = np.zeros(b, dtype=bool)
    epoch = vb_epoch_loops.for_rows(b)
    for k in range(n):
        active = has_meas[:, k] & ~kf.diverged
        if np.any(active):
            p_nom = kf.P / dd  # P̃⁻ in scaled units
            # model, checks, N iterations, hand-over: P̂⁻ (p_out), σ̂_a, û, Û, κ per trial
            epoch(
                k, p_nom, kf.q_hat, kf.b_hat, kf.p_hat, ~active, gyro, ads_q, ads_rate, d, e,
                consts, settings, flags, q_step, u, u_scale, kf.sigma_a, p_out, kap, bad,
            )  # fmt: skip
            kf.diverged |= bad  # a non-finite VB step ends the trial (NaN rows from here on)
            kf.P = p_out * dd
            kappa_log[:, k] = kap
        sigma_log[:, k] = kf.sigma_a
        dof_log[:, k] = u
        rec = step_recording(kf, data, k, k + 1, 1.0, cov)  # update with P̂⁻, σ̂_a; nominal Q̃
        est[:, k] = rec.est[:, 0]
    # κ reported: the geometric mean over the nine calibration terms
    kappa = np.exp(np.mean(np.log(kappa_log), axis=-1))
    return MethodOutput(
        est=est,
        diverged=kf.diverged.copy(),
        kappa=kappa,
        logs={"kappa_terms": kappa_log, "sigma_a": sigma_log, "r_dof": dof_log},
        cov=cov.cov,
        notes={
            "vbakf": (
                f"N = {st.iterations}, τ = {st.tau:g}, ρ = {st.forgetting:.4g}; "
                "κ = effective inflation of the calibration block (clipped)"
            )
        },
    )
