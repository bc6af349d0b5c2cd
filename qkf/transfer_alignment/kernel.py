r"""Compiled inner loop of the transfer-alignment filter (:mod:`qkf.transfer_alignment.filter`).

One call of :func:`run_block` runs a block of epochs for every trial: trials in parallel
(``prange``), epochs in sequence. Per epoch and trial (equations in ``docs/models.md``):

1. ``A = (I + K(p̂))⁻¹``, ``ω̂ = A (ω̃ − b̂)``
   (:func:`~qkf.transfer_alignment.model_compiled.rate_estimate`);
2. with an ADS measurement, the Joseph-form update and the reset
   ``Ĉ ← Ĉ Exp(δθ)``, ``b̂ += Δb``, ``p̂ += Δp`` (:func:`_measurement_update_and_reset`);
3. the records of the a-posteriori estimate (:func:`_record_posterior`);
4. the propagation ``Ĉ ← Ĉ Exp(ω̂ Δt)`` (:func:`_propagate_attitude`) and
   ``P̃ ← Φ̃ P̃ Φ̃ᵀ + Q̃d`` (:func:`~qkf.transfer_alignment.model_compiled.phi_top_rows`,
   :func:`_qd_quadrature`,
   :func:`_propagate_covariance`), with the correlated-noise terms
   (:func:`_correlation_correction`).

Scaled units
------------
The physical variances are far apart: in the ``paper`` configurations the diagonal of ``P`` runs
from about 1e-6 (calibration prior, (1500 ppm)²) down to about 1e-17 (bias, (rad/s)², once
converged), with the attitude in between (1e-10 … 1e-12 rad²). The kernel therefore never
holds ``P`` itself but the covariance scaled by the prior sigmas ``d`` (``FilterParams.p0_sigma``,
SI), and scales every measurement row by its nominal sigma ``e``::

    D = diag(d)                              (15 states: δθ rad, δb rad/s, δp 1)
    E = diag(e),  e_a = σ_a                  (attitude rows 0..2, per trial)
                  e_r = √(σ_r² + σ_v²/Δt)    (rate rows 3..5)

    P̃ = D⁻¹ P D⁻¹        x̃ = D⁻¹ δx         Φ̃ = D⁻¹ Φ D        Q̃d = D⁻¹ Q_d D⁻¹
    ν̃ = E⁻¹ ν            H̃ = E⁻¹ H D        R̃ = E⁻¹ R E⁻¹      C̃ = D⁻¹ C E⁻¹

so that ``S̃ = H̃ P̃ H̃ᵀ + R̃ = E⁻¹ S E⁻¹``, ``K̃ = P̃ H̃ᵀ S̃⁻¹ = D⁻¹ K E`` and ``K̃ ν̃ = D⁻¹ K ν``.
``C = E[w_θ v_rᵀ]`` is the cross-covariance of the attitude process noise and the rate
measurement noise; only its attitude-by-rate block ``C̃_θr = D_θ⁻¹ C_θr / e_r`` is non-zero.
At the start ``P̃ = I`` and ``R̃_a = I``: every matrix the arithmetic touches is of order one
instead of spanning 11 decades, so the sums in the Joseph update and the Cholesky factor of ``S̃``
lose no digits to the choice of units. Unchanged by the scaling: ``ν̃ᵀ S̃⁻¹ ν̃ = νᵀ S⁻¹ ν``; SI is
recovered as ``P = D P̃ D``, ``δx = D x̃``, ``log det S = log det S̃ + 2 Σᵢ log eᵢ``,
``tr S_aa = e_a² tr S̃_aa``. Inputs, estimates and records are in SI.

The model pieces (``A``, ``ω̂``, ``A Ω``, ``R``, ``Γ``, the rows of ``Φ``, the attitude residual)
are those of :mod:`qkf.transfer_alignment.model_compiled`, the rotation algebra that of
:mod:`qkf.core.quat`; both are compiled with the same options as this module
(:mod:`qkf.core.jit`). The math is that of :mod:`qkf.transfer_alignment.model` (numpy); tests
check the two against each other. Quaternions are scalar-last, as scipy stores them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from qkf.core.jit import kernel_jit, row_loops
from qkf.core.kalman import (
    cholesky_inplace,
    forward_solve,
    make_workspace,
    update_sized,
)
from qkf.core.quat import quat_mul_exp, skew_and_square
from qkf.transfer_alignment.model_compiled import (
    OM_COL,
    OM_ROW,
    a_omega,
    attitude_residual,
    attitude_transition,
    phi_top_rows,
    rate_estimate,
)


class FilterState(NamedTuple):
    """Filter state of B trials, updated in place by :func:`run_block`."""

    q_hat: np.ndarray  # (B, 4) Ĉ, scalar-last quaternion
    b_hat: np.ndarray  # (B, 3) b̂, rad/s
    p_hat: np.ndarray  # (B, 9) p̂
    pt: np.ndarray  # (B, 15, 15) P̃ = D⁻¹ P D⁻¹
    diverged: np.ndarray  # (B,) bool; a diverged trial is frozen and records NaN


class Inputs(NamedTuple):
    """Data of one block of n epochs (SI)."""

    gyro: np.ndarray  # (B, n, 3) ω̃, rad/s
    ads_q: np.ndarray  # (B, n, 4) ADS attitude
    ads_rate: np.ndarray  # (B, n, 3) ADS rate, rad/s
    has_meas: np.ndarray  # (B, n) bool
    kappa: np.ndarray  # (B, n, 9): q_p of each calibration component = κ · q_p0
    sigma_a: np.ndarray  # (B,) attitude measurement sigma assumed per trial, rad
    q_scale: np.ndarray  # (B, 2): factors on σ_v² (attitude) and σ_u² (bias) in Q, per trial


class Constants(NamedTuple):
    """Filter constants (SI) shared by all trials."""

    dt: float  # Δt, s
    sigma_v: float  # ARW, rad/√s
    sigma_u: float  # RRW, rad/s^1.5
    qp0: float  # nominal calibration random-walk density, 1/s
    sigma_r: float  # ADS rate sigma, rad/s
    use_rate: bool  # attitude-and-rate matching (6 rows) instead of attitude only (3)
    correlated: bool  # account for the gyro noise shared by z_r,k and the step k → k+1
    d: np.ndarray  # (15,) state scale: prior sigmas
    gl_s: np.ndarray  # (k, m) Gauss–Legendre nodes on [0, 1]; row i has i + 2 nodes
    gl_w: np.ndarray  # (k, m) weights on [0, 1], zero-padded


class Records(NamedTuple):
    """Per-epoch outputs, written by :func:`run_block` (SI)."""

    est: np.ndarray  # (B, n, 16): q̂, b̂, p̂ after the update
    var: np.ndarray  # (B, n, 15): diag P after the update
    cov: np.ndarray  # (B, n or 0, 15, 15): P after the update (axis 1 empty: not recorded)
    dx: np.ndarray  # (B, n, 15): correction applied at the update
    innov: np.ndarray  # (B, n, 6): innovation (NaN where absent)
    stats: np.ndarray  # (B, n, 5): NIS att., NIS rate, NIS, log det S, tr S_aa
    rate: np.ndarray  # (B, n, 3): ω̂ used for propagation, rad/s


StateTuple = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""The fields of :class:`FilterState` as a plain tuple (:func:`run_block_serial`)."""
InputsTuple = tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]
"""The fields of :class:`Inputs` as a plain tuple."""
ConstantsTuple = tuple[
    float, float, float, float, float, bool, bool, np.ndarray, np.ndarray, np.ndarray
]
"""The fields of :class:`Constants` as a plain tuple."""
RecordsTuple = tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]
"""The fields of :class:`Records` as a plain tuple."""


class _Scales(NamedTuple):
    """Factors between SI and the scaled units, computed once per trial (see the module doc)."""

    e_r: float  # rate-row scale √(σ_r² + σ_v²/Δt), rad/s
    inv_er: float  # 1/e_r
    logdet_r: float  # 6 log e_r: the rate rows' share of log det S − log det S̃
    d_er: np.ndarray  # (15,) d_j / e_r: columns of H̃_r = H_r D / e_r
    rv_scaled: float  # (σ_v²/Δt) / e_r²: R̃_r = rv_scaled A Aᵀ + rr_scaled I
    rr_scaled: float  # σ_r² / e_r²
    ratio: np.ndarray  # (3, 15) d_j / d_i: Φ̃_ij = Φ_ij d_j / d_i
    inv_dd: np.ndarray  # (3, 15) 1 / (d_i d_j): Q̃d_ij = Q_d,ij / (d_i d_j)
    inv_d2: np.ndarray  # (15,) 1 / d_i²
    corr_scale: np.ndarray  # (3,) (σ_v²/Δt) / (d_i e_r): C̃_θr = D_θ⁻¹ C_θr / e_r
    max_nodes: int  # most Gauss–Legendre nodes available


class _Scratch(NamedTuple):
    """Per-trial work arrays (contents undefined between uses)."""

    a: np.ndarray  # (3, 3) A = (I + K(p̂))⁻¹
    w: np.ndarray  # (3,) ω̂
    aom: np.ndarray  # (3, 9) A Ω(ω̂)
    h: np.ndarray  # (m, NP) H̃, zero in the padding column
    r: np.ndarray  # (m, m) R̃
    x: np.ndarray  # (NP,) x̃ = D⁻¹ δx, then δx (zero in the padding entry)
    nu: np.ndarray  # (m,) ν̃
    s_keep: np.ndarray  # (m, m) S̃
    ws: tuple[np.ndarray, ...]  # update workspace (NP columns): Kᵀ, chol(S̃), S̃⁻¹ ν̃, ...
    vec: np.ndarray  # (3,)
    y3: np.ndarray  # (3,)
    s3: np.ndarray  # (3, 3)
    wx: np.ndarray  # (3, 3) [−ω̂×]
    wx2: np.ndarray  # (3, 3) [−ω̂×]²
    rr: np.ndarray  # (3, 3) R(s) = Exp(−ω̂ s)
    gg: np.ndarray  # (3, 3) Γ(s) = s J(−ω̂ s)
    q_c: np.ndarray  # (9,) q_p = κ q_p0
    dq: np.ndarray  # (3,) diagonal of σ_u² I + Ω diag(q_p) Ωᵀ
    m1: np.ndarray  # (3, 3)
    m2: np.ndarray  # (3, 3)
    gm2: np.ndarray  # (3, 3)
    q_tt: np.ndarray  # (3, 3) ∫ R M1 Rᵀ + Γ M2 Γᵀ ds
    g_int: np.ndarray  # (3, 3) ∫ Γ ds
    phi_top: np.ndarray  # (3, 15) rows 0..2 of Φ̃
    t_mat: np.ndarray  # (3, 15) Φ̃_top P̃
    tmp: np.ndarray  # (3, 3)
    c_tr: np.ndarray  # (3, 3) C̃_θr
    w_corr: np.ndarray  # (3, 15)
    sinv_rr: np.ndarray  # (3, 3)
    p: np.ndarray  # (NP, NP) P̃ of the trial, padded by a zero row and column


@kernel_jit()
def _nodes_needed(theta: float, max_nodes: int) -> int:
    """Gauss–Legendre nodes for Q_d at rotation angle θ = |ω̂|Δt (rad) per step.

    Relative error against Van Loan's method stays below ~1e-15 with 3 nodes up to
    θ = 0.005 (0.3 deg/s at 1 s steps) and with 4 nodes up to θ = 0.1 (5.7 deg/s); faster
    rotations use ``max_nodes`` (checked in tests/test_model.py and tests/test_filter.py).
    """
    if theta < 0.005:
        n = 3
    elif theta < 0.1:
        n = 4
    else:
        n = max_nodes
    return min(n, max_nodes)


@kernel_jit()
def _nis_block(s_full: np.ndarray, nu: np.ndarray, lo: int, s: np.ndarray, y: np.ndarray) -> float:
    """νᵀ S⁻¹ ν restricted to rows/cols lo:lo+3 of S (marginal NIS of one measurement block).

    ``s`` (3×3) and ``y`` (3) are scratch.
    """
    for i in range(3):
        y[i] = nu[lo + i]
        for j in range(3):
            s[i, j] = s_full[lo + i, lo + j]
    if not cholesky_inplace(s):
        return np.nan
    forward_solve(s, y)
    return y[0] * y[0] + y[1] * y[1] + y[2] * y[2]


@kernel_jit(inline=True)
def _times_top_t(a: np.ndarray, phi_top: np.ndarray, out: np.ndarray) -> None:
    """``out = A Φ̃_topᵀ`` (3 × 3) for ``A`` (3 × 15) and the attitude rows ``Φ̃_top`` (3 × 15)
    of Φ̃: the attitude block of ``A Φ̃ᵀ``. Inlined, so the loops keep their constant sizes."""
    for i in range(3):
        for j in range(3):
            v = 0.0
            for c in range(15):
                v += a[i, c] * phi_top[j, c]
            out[i, j] = v


@kernel_jit()
def _correlation_correction(
    p: np.ndarray,
    q_hat: np.ndarray,
    ws: tuple[np.ndarray, ...],
    c_tr: np.ndarray,
    phi_top: np.ndarray,
    w_corr: np.ndarray,
    sinv_rr: np.ndarray,
    vec: np.ndarray,
    d: np.ndarray,
    v_tt: np.ndarray,
) -> None:
    """Prediction terms for process noise correlated with the rate measurement noise.

    With ``C = E[w_k v_kᵀ]`` (non-zero only between the attitude process noise and the rate
    rows), the one-step prediction of the Kalman filter becomes (e.g. Simon 2006, §7.1)::

        x̂⁻_{k+1} = Φ x̂⁺_k + C S⁻¹ ν
        P⁻_{k+1} = Φ P⁺_k Φᵀ + Q − Φ K Cᵀ − C Kᵀ Φᵀ − C S⁻¹ Cᵀ

    Everything here is in the scaled units of the kernel; ``ws`` holds ``Kᵀ``, the Cholesky
    factor of ``S`` and ``S⁻¹ ν`` from the update of this epoch.
    """
    kt = ws[1]
    chol = ws[4]
    y = ws[5]
    # W = C̃_θr K̃_rᵀ (3×15)
    for i in range(3):
        for j in range(15):
            v = 0.0
            for c in range(3):
                v += c_tr[i, c] * kt[3 + c, j]
            w_corr[i, j] = v
    # V = W Φ̃ᵀ: columns ≥ 3 of Φ̃ᵀ are the identity
    _times_top_t(w_corr, phi_top, v_tt)
    for i in range(3):
        for j in range(3, 15):
            p[i, j] -= w_corr[i, j]
            p[j, i] -= w_corr[i, j]
    # C̃ (S̃⁻¹)_rr C̃ᵀ = X Xᵀ with X = C̃ L_rr⁻ᵀ: the rr block of S⁻¹ = L⁻ᵀ L⁻¹ is L_rr⁻ᵀ L_rr⁻¹
    # because L⁻¹ is lower triangular.
    for i in range(3):
        for j in range(3):  # row i of X solves L_rr xᵢ = c̃ᵢ (forward substitution)
            v = c_tr[i, j]
            for c in range(j):
                v -= chol[3 + j, 3 + c] * sinv_rr[i, c]
            sinv_rr[i, j] = v / chol[3 + j, 3 + j]
    for i in range(3):
        for j in range(3):
            v = 0.0
            for c in range(3):
                v += sinv_rr[i, c] * sinv_rr[j, c]
            p[i, j] -= v + v_tt[i, j] + v_tt[j, i]
    for i in range(3):
        for j in range(i + 1, 3):
            v = 0.5 * (p[i, j] + p[j, i])
            p[i, j] = v
            p[j, i] = v
    # predicted attitude error C̃ S̃⁻¹ ν̃, folded into Ĉ
    for i in range(3):
        v = 0.0
        for c in range(3):
            v += c_tr[i, c] * y[3 + c]
        vec[i] = v * d[i]
    quat_mul_exp(q_hat, vec, q_hat)


@kernel_jit(nrt=True)
def _scale_factors(c: Constants) -> _Scales:
    """The constant factors between SI and the scaled units (module doc), no divisions later."""
    d = c.d
    # e_r = √(σ_r² + σ_v²/Δt)
    e_r = np.sqrt(c.sigma_r**2 + c.sigma_v**2 / c.dt)
    inv_er = 1.0 / e_r
    logdet_r = 6.0 * np.log(e_r)
    # H̃_r = H_r D / e_r,  R̃_r = (σ_v²/Δt · A Aᵀ + σ_r² I) / e_r²
    d_er = d * inv_er
    rv_scaled = c.sigma_v**2 / c.dt * inv_er**2
    rr_scaled = (c.sigma_r * inv_er) ** 2
    # Φ̃_ij = Φ_ij d_j / d_i,  Q̃d_ij = Q_d,ij / (d_i d_j)  (rows i = 0..2)
    ratio = np.empty((3, 15))
    inv_dd = np.empty((3, 15))
    for i in range(3):
        for j in range(15):
            ratio[i, j] = d[j] / d[i]
            inv_dd[i, j] = 1.0 / (d[i] * d[j])
    inv_d2 = 1.0 / (d * d)
    # C̃_θr = D_θ⁻¹ (Γ A (σ_v²/Δt) Aᵀ) / e_r
    corr_scale = c.sigma_v**2 / c.dt / (d[0:3] * e_r)
    max_nodes = c.gl_s.shape[0] + 1
    return _Scales(
        e_r,
        inv_er,
        logdet_r,
        d_er,
        rv_scaled,
        rr_scaled,
        ratio,
        inv_dd,
        inv_d2,
        corr_scale,
        max_nodes,
    )


@kernel_jit(nrt=True)
def _make_scratch(m: int) -> _Scratch:
    """Work arrays of one trial for ``m`` measurement rows."""
    return _Scratch(
        np.empty((3, 3)),  # a
        np.empty(3),  # w
        np.empty((3, 9)),  # aom
        np.zeros((m, NP)),  # h: only its structural non-zeros are ever written
        np.zeros((m, m)),  # r: idem
        np.zeros(NP),  # x
        np.empty(m),  # nu
        np.empty((m, m)),  # s_keep
        make_workspace(NP, m),  # ws
        np.empty(3),  # vec
        np.empty(3),  # y3
        np.empty((3, 3)),  # s3
        np.empty((3, 3)),  # wx
        np.empty((3, 3)),  # wx2
        np.empty((3, 3)),  # rr
        np.empty((3, 3)),  # gg
        np.empty(9),  # q_c
        np.empty(3),  # dq
        np.empty((3, 3)),  # m1
        np.empty((3, 3)),  # m2
        np.empty((3, 3)),  # gm2
        np.empty((3, 3)),  # q_tt
        np.empty((3, 3)),  # g_int
        np.empty((3, 15)),  # phi_top
        np.empty((3, 15)),  # t_mat
        np.empty((3, 3)),  # tmp
        np.empty((3, 3)),  # c_tr
        np.empty((3, 15)),  # w_corr
        np.empty((3, 3)),  # sinv_rr
        np.zeros((NP, NP)),  # p
    )


NP = 16
"""The state dimension the update works in: the 15 states and one zero padding entry, so that
rows of P̃ are two vectors of eight (or four of four) with no remainder."""


@kernel_jit()
def _update_padded(
    x: np.ndarray,
    p: np.ndarray,
    nu: np.ndarray,
    h: np.ndarray,
    r: np.ndarray,
    s_out: np.ndarray,
    ws: tuple[np.ndarray, ...],
    m: int,
) -> tuple[bool, float, float]:
    """The Joseph-form update :func:`qkf.core.kalman.update_sized` of one trial on the padded
    arrays (``x`` (NP,), ``p`` (NP, NP), ``h`` (m, NP)), with n = NP and m = 3 or 6 constants
    at compile time: each branch is a copy specialised to its sizes.

    The padding row and column of ``p`` stay zero: ``H̃`` is zero in the padding column, so
    ``U = H̃ P̃``, ``K̃`` and the correction are zero there too. The numbers differ from the
    unpadded update only by the rounding of reassociated sums (docs/performance.md).
    """
    if m == 6:
        return update_sized(x, p, nu, h, r, s_out, ws, NP, 6, True)
    return update_sized(x, p, nu, h, r, s_out, ws, NP, 3, True)


@kernel_jit(inline=True)
def _record_diverged(rec: Records, bi: int, k: int) -> None:
    """NaN in every record of epoch ``k`` of a diverged trial."""
    for i in range(16):
        rec.est[bi, k, i] = np.nan
    for i in range(15):
        rec.var[bi, k, i] = np.nan
        rec.dx[bi, k, i] = np.nan
    for i in range(6):
        rec.innov[bi, k, i] = np.nan
    for i in range(5):
        rec.stats[bi, k, i] = np.nan
    for i in range(3):
        rec.rate[bi, k, i] = np.nan
    if rec.cov.shape[1] > 0:
        for i in range(15):
            for j in range(15):
                rec.cov[bi, k, i, j] = np.nan


@kernel_jit(inline=True)
def _measurement_update_and_reset(
    q_hat: np.ndarray,  # (4,) in/out
    b_hat: np.ndarray,  # (3,) in/out
    p_hat: np.ndarray,  # (9,) in/out
    p: np.ndarray,  # (15, 15) P̃, in/out
    gyro: np.ndarray,  # (3,) ω̃_k
    ads_q: np.ndarray,  # (4,)
    ads_rate: np.ndarray,  # (3,)
    e_a: float,  # σ_a of this trial
    use_rate: bool,
    d: np.ndarray,
    sc: _Scales,
    s: _Scratch,  # in: a, w of the prior estimate; out: x = δx (SI), a, w after the reset
    innov: np.ndarray,  # (6,) out: ν (SI)
    stats: np.ndarray,  # (5,) out
) -> tuple[bool, bool]:
    """Joseph-form update in scaled units, its statistics and the reset.

    Returns ``(updated, rate_ok)``: whether ``S̃`` was positive definite (else nothing changed)
    and whether ``I + K(p̂)`` is still invertible after the reset.
    """
    a, w, h, r, nu = s.a, s.w, s.h, s.r, s.nu
    inv_ea = 1.0 / e_a
    # attitude rows: z_a = Log(Ĉᵀ C_ADS);  ν̃_a = z_a/e_a,  H̃_a = [D_θ/e_a, 0, 0],  R̃_a = I
    attitude_residual(q_hat, ads_q, s.vec)
    for i in range(3):
        innov[i] = s.vec[i]
        nu[i] = s.vec[i] * inv_ea
        h[i, i] = d[i] * inv_ea
        r[i, i] = 1.0
    if use_rate:
        # rate rows: z_r = ω_ADS − ω̂;  ν̃_r = z_r/e_r,  H̃_r = [0, −A, −A Ω(ω̂)] D / e_r,
        # R̃_r = (σ_v²/Δt · A Aᵀ + σ_r² I) / e_r²
        a_omega(a, w, s.aom)
        for i in range(3):
            zr = ads_rate[i] - w[i]
            innov[3 + i] = zr
            nu[3 + i] = zr * sc.inv_er
            for j in range(3):
                h[3 + i, 3 + j] = -a[i, j] * sc.d_er[3 + j]
                aat = a[i, 0] * a[j, 0] + a[i, 1] * a[j, 1] + a[i, 2] * a[j, 2]
                r[3 + i, 3 + j] = sc.rv_scaled * aat
            r[3 + i, 3 + i] += sc.rr_scaled
            for l in range(9):
                h[3 + i, 6 + l] = -s.aom[i, l] * sc.d_er[6 + l]
    # S̃ = H̃ P̃ H̃ᵀ + R̃,  K̃ = P̃ H̃ᵀ S̃⁻¹,  x̃ = K̃ ν̃,  P̃ ← (I − K̃H̃) P̃ (I − K̃H̃)ᵀ + K̃ R̃ K̃ᵀ
    ok, nis, logdet = _update_padded(s.x, p, nu, h, r, s.s_keep, s.ws, 6 if use_rate else 3)
    if not ok:
        return False, True
    # log det S = log det S̃ + 2 Σ log eᵢ
    scale_logdet = 6.0 * np.log(e_a)
    if use_rate:
        scale_logdet += sc.logdet_r
    # the leading 3×3 block of chol(S̃) is chol(S̃_aa): the attitude NIS ν̃_aᵀ S̃_aa⁻¹ ν̃_a is
    # one forward substitution
    chol = s.ws[4]
    y3 = s.y3
    for i in range(3):
        v = nu[i]
        for c in range(i):
            v -= chol[i, c] * y3[c]
        y3[i] = v / chol[i, i]
    stats[0] = y3[0] ** 2 + y3[1] ** 2 + y3[2] ** 2
    stats[1] = _nis_block(s.s_keep, nu, 3, s.s3, y3) if use_rate else np.nan
    stats[2] = nis
    stats[3] = logdet + scale_logdet
    # tr S_aa = e_a² tr S̃_aa
    stats[4] = (s.s_keep[0, 0] + s.s_keep[1, 1] + s.s_keep[2, 2]) * e_a**2
    # δx = D x̃;  reset: Ĉ ← Ĉ Exp(δθ), b̂ += Δb, p̂ += Δp
    x = s.x
    for i in range(15):
        x[i] *= d[i]
    quat_mul_exp(q_hat, x[0:3], q_hat)
    for i in range(3):
        b_hat[i] += x[3 + i]
    for i in range(9):
        p_hat[i] += x[6 + i]
    # fresh A, ω̂ for the propagation
    return True, rate_estimate(gyro, b_hat, p_hat, a, w)


@kernel_jit(inline=True)
def _record_posterior(
    rec: Records,
    bi: int,
    k: int,
    q_hat: np.ndarray,
    b_hat: np.ndarray,
    p_hat: np.ndarray,
    p: np.ndarray,
    d: np.ndarray,
    s: _Scratch,
) -> bool:
    """Record the a-posteriori estimate, ``δx``, ``ω̂`` and ``P = D P̃ D``; False unless every
    diagonal entry of ``P̃`` is finite and positive."""
    for i in range(15):
        rec.dx[bi, k, i] = s.x[i]
    for i in range(4):
        rec.est[bi, k, i] = q_hat[i]
    for i in range(3):
        rec.est[bi, k, 4 + i] = b_hat[i]
        rec.rate[bi, k, i] = s.w[i]
    for i in range(9):
        rec.est[bi, k, 7 + i] = p_hat[i]
    ok = True
    for i in range(15):
        # P_ii = d_i² P̃_ii
        rec.var[bi, k, i] = p[i, i] * d[i] * d[i]
        if not (np.isfinite(p[i, i]) and p[i, i] > 0.0):
            ok = False
    if rec.cov.shape[1] > 0:
        for i in range(15):
            for j in range(15):
                # P_ij = d_i d_j P̃_ij
                rec.cov[bi, k, i, j] = p[i, j] * (d[i] * d[j])
    return ok


@kernel_jit(inline=True)
def _propagate_attitude(q_hat: np.ndarray, w: np.ndarray, dt: float, s: _Scratch) -> None:
    """Ĉ ← Ĉ Exp(ω̂ Δt)."""
    for i in range(3):
        s.vec[i] = w[i] * dt
    quat_mul_exp(q_hat, s.vec, q_hat)


@kernel_jit(inline=True)
def _noise_correlation(
    gg: np.ndarray, a: np.ndarray, corr_scale: np.ndarray, c_tr: np.ndarray
) -> None:
    """C̃_θr = D_θ⁻¹ C_θr / e_r with C_θr = E[w_θ v_rᵀ] = Γ A (σ_v²/Δt) Aᵀ, into ``c_tr``.

    ``gg`` = Γ(Δt); ``corr_scale`` = (σ_v²/Δt) / (d_θ e_r).
    """
    for i in range(3):
        for j in range(3):
            v = 0.0
            for c in range(3):
                v += gg[i, c] * (a[j, 0] * a[c, 0] + a[j, 1] * a[c, 1] + a[j, 2] * a[c, 2])
            c_tr[i, j] = v * corr_scale[i]


@kernel_jit(inline=True)
def _qd_quadrature(
    wx: np.ndarray,
    wx2: np.ndarray,
    rate: float,
    a: np.ndarray,
    w: np.ndarray,
    c: Constants,
    max_nodes: int,
    s: _Scratch,
    sv2: float,
    su2: float,
) -> None:
    """Attitude integrals of Q_d by Gauss–Legendre quadrature over s ∈ [0, Δt], in SI::

        q_tt  = ∫ R(s) M1 R(s)ᵀ + Γ(s) M2 Γ(s)ᵀ ds     into s.q_tt
        ∫Γ    = ∫ Γ(s) ds                               into s.g_int
        M1 = σ_v² A Aᵀ,   M2 = A (σ_u² I + Ω diag(q_p) Ωᵀ) Aᵀ

    ``sv2``, ``su2``: σ_v², σ_u² of the process noise (the constants' times the trial's
    ``q_scale``).

    with R(s) = Exp(−ω̂ s), Γ(s) = s J(−ω̂ s); ``wx``, ``wx2`` = [−ω̂×], [−ω̂×]², ``rate`` = |ω̂|.
    ``s.q_c`` holds q_p = κ q_p0. The node count comes from :func:`_nodes_needed`. Clobbers
    ``s.rr``, ``s.gg``, ``s.tmp``.
    """
    dt = c.dt
    q_c, dq, m1, m2, q_tt, g_int = s.q_c, s.dq, s.m1, s.m2, s.q_tt, s.g_int
    rr, gg, tmp, gm2 = s.rr, s.gg, s.tmp, s.gm2
    # Ω diag(q) Ωᵀ is diagonal because each column of Ω has a single non-zero:
    # dq_r = σ_u² + Σ_{l: row l = r} q_l ω_{col l}²
    for r_ in range(3):
        dq[r_] = su2
    for l in range(9):
        dq[OM_ROW[l]] += q_c[l] * w[OM_COL[l]] ** 2
    for i in range(3):
        for j in range(3):
            aat = a[i, 0] * a[j, 0] + a[i, 1] * a[j, 1] + a[i, 2] * a[j, 2]
            # M1 = σ_v² A Aᵀ,  M2 = A diag(dq) Aᵀ
            m1[i, j] = sv2 * aat
            m2[i, j] = (
                a[i, 0] * dq[0] * a[j, 0] + a[i, 1] * dq[1] * a[j, 1] + (a[i, 2] * dq[2] * a[j, 2])
            )
            q_tt[i, j] = 0.0
            g_int[i, j] = 0.0
    n_nodes = _nodes_needed(rate * dt, max_nodes)
    for nd in range(n_nodes):
        # node s_j and weight w_j on [0, Δt]
        s_j = c.gl_s[n_nodes - 2, nd] * dt
        w_j = c.gl_w[n_nodes - 2, nd] * dt
        attitude_transition(wx, wx2, rate, s_j, rr, gg)
        for i in range(3):
            for j in range(3):
                v1 = 0.0
                v2 = 0.0
                for k in range(3):
                    v1 += rr[i, k] * m1[k, j]
                    v2 += gg[i, k] * m2[k, j]
                tmp[i, j] = v1
                gm2[i, j] = v2
        for i in range(3):
            for j in range(3):
                # q_tt += w_j (R M1 Rᵀ + Γ M2 Γᵀ),  ∫Γ += w_j Γ
                v = 0.0
                for k in range(3):
                    v += tmp[i, k] * rr[j, k] + gm2[i, k] * gg[j, k]
                q_tt[i, j] += w_j * v
                g_int[i, j] += w_j * gg[i, j]


@kernel_jit(inline=True)
def _propagate_covariance(
    p: np.ndarray,
    q_hat: np.ndarray,
    a: np.ndarray,
    c: Constants,
    sc: _Scales,
    s: _Scratch,
    correlated: bool,
    su2: float,
) -> None:
    """P̃ ← Φ̃ P̃ Φ̃ᵀ + Q̃d, then (``correlated``) the correlated-noise terms.

    Only rows/columns 0..2 of Φ̃ P̃ Φ̃ᵀ differ from P̃ (the other rows of Φ are the identity's),
    and Q̃d = D⁻¹ Q_d D⁻¹ with (SI, rows θ, b, p; see :func:`_qd_quadrature`)::

        Q_θθ = q_tt,   Q_θb = −σ_u² (∫Γ) A,   Q_θp = −(∫Γ) A Ω diag(q_p),
        Q_bb = σ_u² Δt I,   Q_pp = diag(q_p) Δt,   Q_bp = 0

    Reads ``s.phi_top``, ``s.q_tt``, ``s.g_int``, ``s.aom``, ``s.q_c`` (and ``s.c_tr``, the
    update's workspace ``s.ws`` when ``correlated``). The correction folds C̃ S̃⁻¹ ν̃ into
    ``q_hat``.
    """
    phi_top, t_mat, tmp, aom, q_c = s.phi_top, s.t_mat, s.tmp, s.aom, s.q_c
    q_tt, g_int = s.q_tt, s.g_int
    inv_dd = sc.inv_dd
    # T = Φ̃_top P̃ (3×15)
    for i in range(3):
        for j in range(15):
            t_mat[i, j] = 0.0
        for k in range(15):
            coef = phi_top[i, k]
            for j in range(15):
                t_mat[i, j] += coef * p[k, j]
    # (Φ̃ P̃ Φ̃ᵀ)_θθ = T Φ̃_topᵀ
    _times_top_t(t_mat, phi_top, tmp)
    # (Φ̃ P̃ Φ̃ᵀ)_θj = T_θj for j ≥ 3; the rest of P̃ stays
    for i in range(3):
        for j in range(3, 15):
            p[i, j] = t_mat[i, j]
            p[j, i] = t_mat[i, j]
    # P̃_θθ = sym(T Φ̃_topᵀ) + sym(q_tt) / (d_i d_j)
    for i in range(3):
        for j in range(3):
            p[i, j] = 0.5 * (tmp[i, j] + tmp[j, i]) + 0.5 * (q_tt[i, j] + q_tt[j, i]) * inv_dd[i, j]
    # + Q̃d off-diagonal attitude blocks: Q̃_θb = −σ_u² (∫Γ) A / (d_θ d_b),
    #   Q̃_θp = −q_p,l ((∫Γ) A Ω)_l / (d_θ d_p,l)
    for i in range(3):
        for j in range(3):
            v = 0.0
            for k in range(3):
                v += g_int[i, k] * a[k, j]
            qtb = -su2 * v * inv_dd[i, 3 + j]
            p[i, 3 + j] += qtb
            p[3 + j, i] += qtb
        for l in range(9):
            v = 0.0
            for k in range(3):
                v += g_int[i, k] * aom[k, l]
            qtp = -q_c[l] * v * inv_dd[i, 6 + l]
            p[i, 6 + l] += qtp
            p[6 + l, i] += qtp
    # + the random-walk diagonals: Q̃_bb = σ_u² Δt / d_b²,  Q̃_pp = q_p Δt / d_p²
    for i in range(3):
        p[3 + i, 3 + i] += su2 * c.dt * sc.inv_d2[3 + i]
    for i in range(9):
        p[6 + i, 6 + i] += q_c[i] * c.dt * sc.inv_d2[6 + i]
    if correlated:
        # P̃ −= Φ̃ K̃ C̃ᵀ + C̃ K̃ᵀ Φ̃ᵀ + C̃ S̃⁻¹ C̃ᵀ,  Ĉ ← Ĉ Exp(D_θ C̃ S̃⁻¹ ν̃)
        _correlation_correction(
            p, q_hat, s.ws, s.c_tr, phi_top, s.w_corr, s.sinv_rr, s.vec, c.d, tmp
        )


@kernel_jit(nrt=True)
def _run_trial(bi: int, state: FilterState, inputs: Inputs, c: Constants, rec: Records) -> None:
    """All epochs of ``inputs`` for trial ``bi``: allocates the trial's work arrays and runs
    :func:`_epoch_loop`. ``state`` and ``rec`` are written in place.

    A trial whose numbers go non-finite, whose ``I + K(p̂)`` turns singular or whose ``S̃`` /
    ``P̃`` loses positive definiteness is flagged in ``state.diverged`` and frozen.
    """
    _epoch_loop(bi, state, inputs, c, rec, _scale_factors(c), _make_scratch(6 if c.use_rate else 3))


@kernel_jit()
def _epoch_loop(
    bi: int,
    state: FilterState,
    inputs: Inputs,
    c: Constants,
    rec: Records,
    sc: _Scales,
    s: _Scratch,
) -> None:
    """Per epoch of trial ``bi``: measurement update and reset, records, then propagation to
    the next epoch (module doc). Compiled without the NRT (see :func:`qkf.core.jit.kernel_jit`)."""
    q_hat, b_hat, p_hat = state.q_hat[bi], state.b_hat[bi], state.p_hat[bi]
    # P̃ padded to NP × NP for the epochs of this call: the update's loops then have constant
    # trip counts (see _update_padded); the padding row and column stay zero throughout
    p = s.p
    pt = state.pt[bi]
    for i in range(15):
        for j in range(15):
            p[i, j] = pt[i, j]
    gyro, ads_q, ads_rate = inputs.gyro[bi], inputs.ads_q[bi], inputs.ads_rate[bi]
    has_meas, kappa = inputs.has_meas[bi], inputs.kappa[bi]
    e_a = inputs.sigma_a[bi]
    # σ_v², σ_u² of the process noise: a factor of 1 leaves them bit for bit
    sv2 = c.sigma_v**2 * inputs.q_scale[bi, 0]
    su2 = c.sigma_u**2 * inputs.q_scale[bi, 1]
    a, w, x = s.a, s.w, s.x
    for k in range(gyro.shape[0]):
        if state.diverged[bi]:
            _record_diverged(rec, bi, k)
            continue
        # A = (I + K(p̂))⁻¹, ω̂ = A (ω̃ − b̂)
        bad = not rate_estimate(gyro[k], b_hat, p_hat, a, w)
        updated_rate = False
        # ---- measurement update and reset ---------------------------------------------------
        for i in range(15):
            x[i] = 0.0
        for i in range(6):
            rec.innov[bi, k, i] = np.nan
        for i in range(5):
            rec.stats[bi, k, i] = np.nan
        if has_meas[k] and not bad:
            updated, rate_ok = _measurement_update_and_reset(
                q_hat,
                b_hat,
                p_hat,
                p,
                gyro[k],
                ads_q[k],
                ads_rate[k],
                e_a,
                c.use_rate,
                c.d,
                sc,
                s,
                rec.innov[bi, k],
                rec.stats[bi, k],
            )
            bad = not (updated and rate_ok)
            updated_rate = updated and c.use_rate and c.correlated
        # ---- record the a-posteriori estimate -------------------------------------------------
        if not _record_posterior(rec, bi, k, q_hat, b_hat, p_hat, p, c.d, s):
            bad = True
        if bad:
            state.diverged[bi] = True
            continue
        # ---- propagate: Ĉ ← Ĉ Exp(ω̂ Δt), P̃ ← Φ̃ P̃ Φ̃ᵀ + Q̃d ------------------------------------
        _propagate_attitude(q_hat, w, c.dt, s)
        for l in range(9):
            s.q_c[l] = kappa[k, l] * c.qp0  # q_p = κ q_p0
        a_omega(a, w, s.aom)
        for i in range(3):
            s.vec[i] = -w[i]
        skew_and_square(s.vec, s.wx, s.wx2)
        rate = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        # R = Exp(−ω̂ Δt), Γ = Δt J(−ω̂ Δt)
        attitude_transition(s.wx, s.wx2, rate, c.dt, s.rr, s.gg)
        if updated_rate:
            _noise_correlation(s.gg, a, sc.corr_scale, s.c_tr)
        phi_top_rows(s.rr, s.gg, a, s.aom, sc.ratio, s.phi_top)
        _qd_quadrature(s.wx, s.wx2, rate, a, w, c, sc.max_nodes, s, sv2, su2)
        _propagate_covariance(p, q_hat, a, c, sc, s, updated_rate, su2)
    for i in range(15):
        for j in range(15):
            pt[i, j] = p[i, j]


run_block = row_loops(_run_trial, "state.q_hat.shape[0]").parallel
"""Run the n epochs of ``inputs`` for every trial (:func:`_run_trial`), trials in parallel.
Batches below :data:`~qkf.core.jit.SERIAL_BELOW` trials (the single environment, a recorded
run) run :func:`run_block_serial` instead."""


@kernel_jit(nrt=True)
def run_block_serial(
    state: StateTuple, inputs: InputsTuple, c: ConstantsTuple, rec: RecordsTuple
) -> None:
    """:func:`run_block` with the trials one after the other in the calling thread (the same
    per-trial code, so the same numbers bit for bit).

    The four groups may be plain tuples in the order of the named tuples' fields
    (:class:`FilterState`, :class:`Inputs`, :class:`Constants`, :class:`Records`): numba types
    a named-tuple argument in Python on every call but a plain tuple from a cached
    fingerprint, which saves about 3 µs of a call that a single environment makes twice per
    step (docs/performance.md).
    """
    st, inp, con, out = FilterState(*state), Inputs(*inputs), Constants(*c), Records(*rec)
    for bi in range(st.q_hat.shape[0]):
        _run_trial(bi, st, inp, con, out)
