"""Compiled inner loop of the transfer-alignment filter (see ``transfer_alignment.py``).

One call runs a block of epochs for every trial: trials in parallel (``prange``), epochs in
sequence. The covariance is held in scaled units ``P̃ = D⁻¹ P D⁻¹`` (``D`` = prior sigmas), and
measurements are scaled by their nominal sigmas, so every matrix the arithmetic touches is of
order one although the physical variances span 1e-10 to 1e-18.

The math is that of ``qkf.transfer_alignment.model`` (numpy); tests check the two against each other. Quaternions
are scalar-last, as scipy stores them.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from qkf.core.kalman import (
    cholesky_inplace,
    forward_solve,
    make_workspace,
    update_one,
)
from qkf.core.quat import normalize as _normalize
from qkf.core.quat import quat_from_rotvec, quat_mul, rotvec_from_quat

# Reassociation lets LLVM vectorise the small reductions; NaN and Inf semantics are kept, so
# the finiteness checks still work.
_FASTMATH = {"reassoc", "contract", "arcp"}

# Column l of Ω(ω) has one non-zero, ω[_OM_COL[l]], in row _OM_ROW[l].
_OM_ROW = np.array([0, 1, 2, 0, 0, 1, 1, 2, 2])
_OM_COL = np.array([0, 1, 2, 1, 2, 2, 0, 0, 1])


@nb.njit(cache=True, fastmath=_FASTMATH)
def _rodrigues(theta: float) -> tuple[float, float, float]:
    """sin θ/θ, (1 − cos θ)/θ², (θ − sin θ)/θ³ (as qkf.core.so3.rodrigues_coefficients)."""
    t2 = theta * theta
    if theta < 0.1:
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0 - t2 * t2 * t2 / 5040.0 + t2**4 / 362880.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2 * t2 * t2 / 40320.0 + t2**4 / 3628800.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0 - t2**3 / 362880.0 + t2**4 / 39916800.0
    else:
        s = np.sin(theta)
        h = np.sin(0.5 * theta)
        a = s / theta
        b = 2.0 * h * h / t2
        c = (theta - s) / (t2 * theta)
    return a, b, c


@nb.njit(cache=True, fastmath=_FASTMATH)
def _skew_sq(w: np.ndarray, out_w: np.ndarray, out_w2: np.ndarray) -> None:
    out_w[0, 0] = 0.0
    out_w[0, 1] = -w[2]
    out_w[0, 2] = w[1]
    out_w[1, 0] = w[2]
    out_w[1, 1] = 0.0
    out_w[1, 2] = -w[0]
    out_w[2, 0] = -w[1]
    out_w[2, 1] = w[0]
    out_w[2, 2] = 0.0
    for i in range(3):
        for j in range(3):
            v = 0.0
            for k in range(3):
                v += out_w[i, k] * out_w[k, j]
            out_w2[i, j] = v


@nb.njit(cache=True, fastmath=_FASTMATH)
def _transition(
    wx: np.ndarray, wx2: np.ndarray, rate: float, s: float, r: np.ndarray, g: np.ndarray
) -> None:
    """R = Exp(−ω̂ s), Γ = s · J(−ω̂ s) into ``r`` and ``g``.

    ``wx`` = [−ω̂×] and ``wx2`` = [−ω̂×]² are computed once per step by the caller; ``rate`` =
    |ω̂| in rad/s. With φ = −ω̂ s: [φ×] = s·wx and [φ×]² = s²·wx2.
    """
    a, b, c = _rodrigues(rate * s)
    a1 = a * s
    b2 = b * s * s
    b1 = b * s
    c2 = c * s * s
    for i in range(3):
        for j in range(3):
            e = 1.0 if i == j else 0.0
            r[i, j] = e + a1 * wx[i, j] + b2 * wx2[i, j]
            g[i, j] = s * (e + b1 * wx[i, j] + c2 * wx2[i, j])


@nb.njit(cache=True, fastmath=_FASTMATH)
def _rate(gyro: np.ndarray, b_hat: np.ndarray, p_hat: np.ndarray, a: np.ndarray, w: np.ndarray):  # type: ignore[no-untyped-def]
    """A = (I + K(p̂))⁻¹ and ω̂ = A (ω̃ − b̂) into ``a`` and ``w``; False if singular."""
    m00, m11, m22 = 1.0 + p_hat[0], 1.0 + p_hat[1], 1.0 + p_hat[2]
    m01, m02, m12 = p_hat[3], p_hat[4], p_hat[5]
    m10, m20, m21 = p_hat[6], p_hat[7], p_hat[8]
    c00 = m11 * m22 - m12 * m21
    c01 = m12 * m20 - m10 * m22
    c02 = m10 * m21 - m11 * m20
    det = m00 * c00 + m01 * c01 + m02 * c02
    if not (abs(det) > 1e-12 and np.isfinite(det)):
        return False
    inv = 1.0 / det
    a[0, 0] = c00 * inv
    a[1, 0] = c01 * inv
    a[2, 0] = c02 * inv
    a[0, 1] = (m02 * m21 - m01 * m22) * inv
    a[1, 1] = (m00 * m22 - m02 * m20) * inv
    a[2, 1] = (m01 * m20 - m00 * m21) * inv
    a[0, 2] = (m01 * m12 - m02 * m11) * inv
    a[1, 2] = (m02 * m10 - m00 * m12) * inv
    a[2, 2] = (m00 * m11 - m01 * m10) * inv
    u0 = gyro[0] - b_hat[0]
    u1 = gyro[1] - b_hat[1]
    u2 = gyro[2] - b_hat[2]
    for i in range(3):
        w[i] = a[i, 0] * u0 + a[i, 1] * u1 + a[i, 2] * u2
    return True


@nb.njit(cache=True, fastmath=_FASTMATH)
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


@nb.njit(cache=True, fastmath=_FASTMATH)
def _a_omega(a: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """``A Ω(ω)`` (3×9) into ``out``."""
    for l in range(9):
        col = _OM_ROW[l]
        v = w[_OM_COL[l]]
        for i in range(3):
            out[i, l] = a[i, col] * v


@nb.njit(cache=True, fastmath=_FASTMATH)
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


@nb.njit(cache=True, fastmath=_FASTMATH)
def _correlation_correction(
    p: np.ndarray,
    q_hat: np.ndarray,
    ws: tuple[np.ndarray, ...],
    c_tr: np.ndarray,
    phi_top: np.ndarray,
    w_corr: np.ndarray,
    sinv_rr: np.ndarray,
    qinc: np.ndarray,
    qtmp: np.ndarray,
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
    for i in range(3):
        for j in range(3):
            v = 0.0
            for c in range(15):
                v += w_corr[i, c] * phi_top[j, c]
            v_tt[i, j] = v
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
    quat_from_rotvec(vec, qinc)
    quat_mul(q_hat, qinc, qtmp)
    _normalize(qtmp)
    for i in range(4):
        q_hat[i] = qtmp[i]


@nb.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def run_block(
    q_hat: np.ndarray,  # (B, 4)   in/out
    b_hat: np.ndarray,  # (B, 3)   in/out, rad/s
    p_hat: np.ndarray,  # (B, 9)   in/out
    pt: np.ndarray,  # (B, 15, 15) in/out, scaled covariance
    diverged: np.ndarray,  # (B,) bool in/out
    gyro: np.ndarray,  # (B, n, 3) rad/s
    ads_q: np.ndarray,  # (B, n, 4)
    ads_rate: np.ndarray,  # (B, n, 3) rad/s
    has_meas: np.ndarray,  # (B, n) bool
    kappa: np.ndarray,  # (B, n, 9): q_p of each calibration component = κ · q_p0
    dt: float,
    sigma_v: float,
    sigma_u: float,
    qp0: float,
    sigma_a: np.ndarray,  # (B,) attitude measurement sigma assumed per trial, rad
    sigma_r: float,
    use_rate: bool,
    correlated: bool,  # account for the gyro noise shared by z_r,k and the step k → k+1
    d: np.ndarray,  # (15,) state scale
    gl_s: np.ndarray,  # (k, m) Gauss-Legendre nodes on [0, 1]; row i has i + 2 nodes
    gl_w: np.ndarray,  # (k, m) weights on [0, 1], zero-padded
    rec_est: np.ndarray,  # (B, n, 16): q̂, b̂, p̂ after the update
    rec_var: np.ndarray,  # (B, n, 15): diag P after the update, SI
    rec_cov: np.ndarray,  # (B, n or 0, 15, 15): P after the update, SI
    rec_dx: np.ndarray,  # (B, n, 15): correction applied at the update, SI
    rec_innov: np.ndarray,  # (B, n, 6): innovation, SI (NaN where absent)
    rec_stats: np.ndarray,  # (B, n, 5): NIS att., NIS rate, NIS, log det S, tr S_aa (SI)
    rec_rate: np.ndarray,  # (B, n, 3): ω̂ used for propagation, rad/s
) -> None:
    n_trials = q_hat.shape[0]
    n_ep = gyro.shape[1]
    m = 6 if use_rate else 3
    full_cov = rec_cov.shape[1] > 0
    e_r = np.sqrt(sigma_r**2 + sigma_v**2 / dt)
    inv_er = 1.0 / e_r
    d_er = d * inv_er
    rv_scaled = sigma_v**2 / dt * inv_er**2
    rr_scaled = (sigma_r * inv_er) ** 2
    # scale factors between SI and the scaled units, computed once (no divisions per step)
    ratio = np.empty((3, 15))  # d_j / d_i
    inv_dd = np.empty((3, 15))  # 1 / (d_i d_j)
    for i in range(3):
        for j in range(15):
            ratio[i, j] = d[j] / d[i]
            inv_dd[i, j] = 1.0 / (d[i] * d[j])
    inv_d2 = 1.0 / (d * d)
    corr_scale = sigma_v**2 / dt / (d[0:3] * e_r)
    max_nodes = gl_s.shape[0] + 1
    for bi in nb.prange(n_trials):
        p = pt[bi]
        e_a = sigma_a[bi]
        inv_ea = 1.0 / e_a
        a = np.empty((3, 3))
        w = np.empty(3)
        aom = np.empty((3, 9))
        h = np.zeros((m, 15))
        r = np.zeros((m, m))
        x = np.zeros(15)
        nu = np.empty(m)
        qtmp = np.empty(4)
        qinc = np.empty(4)
        vec = np.empty(3)
        wx = np.empty((3, 3))
        wx2 = np.empty((3, 3))
        gm2 = np.empty((3, 3))
        q_c = np.empty(9)
        dq = np.empty(3)
        rr = np.empty((3, 3))
        gg = np.empty((3, 3))
        phi_top = np.empty((3, 15))
        t_mat = np.empty((3, 15))
        m1 = np.empty((3, 3))
        m2 = np.empty((3, 3))
        q_tt = np.empty((3, 3))
        g_int = np.empty((3, 3))
        tmp = np.empty((3, 3))
        s_keep = np.empty((m, m))
        c_tr = np.empty((3, 3))
        w_corr = np.empty((3, 15))
        sinv_rr = np.empty((3, 3))
        s3 = np.empty((3, 3))
        y3 = np.empty(3)
        ws = make_workspace(15, m)
        for k in range(n_ep):
            if diverged[bi]:
                for i in range(16):
                    rec_est[bi, k, i] = np.nan
                for i in range(15):
                    rec_var[bi, k, i] = np.nan
                    rec_dx[bi, k, i] = np.nan
                for i in range(6):
                    rec_innov[bi, k, i] = np.nan
                for i in range(5):
                    rec_stats[bi, k, i] = np.nan
                for i in range(3):
                    rec_rate[bi, k, i] = np.nan
                if full_cov:
                    rec_cov[bi, k, :, :] = np.nan
                continue
            bad = not _rate(gyro[bi, k], b_hat[bi], p_hat[bi], a, w)
            updated_rate = False
            # ---- measurement update -------------------------------------------------------
            for i in range(15):
                x[i] = 0.0
            for i in range(6):
                rec_innov[bi, k, i] = np.nan
            for i in range(5):
                rec_stats[bi, k, i] = np.nan
            if has_meas[bi, k] and not bad:
                qtmp[0] = -q_hat[bi, 0]
                qtmp[1] = -q_hat[bi, 1]
                qtmp[2] = -q_hat[bi, 2]
                qtmp[3] = q_hat[bi, 3]
                quat_mul(qtmp, ads_q[bi, k], qinc)
                rotvec_from_quat(qinc, vec)
                for i in range(3):
                    rec_innov[bi, k, i] = vec[i]
                    nu[i] = vec[i] * inv_ea
                    h[i, i] = d[i] * inv_ea
                    r[i, i] = 1.0
                if use_rate:
                    _a_omega(a, w, aom)
                    for i in range(3):
                        zr = ads_rate[bi, k, i] - w[i]
                        rec_innov[bi, k, 3 + i] = zr
                        nu[3 + i] = zr * inv_er
                        for j in range(3):
                            h[3 + i, 3 + j] = -a[i, j] * d_er[3 + j]
                            aat = a[i, 0] * a[j, 0] + a[i, 1] * a[j, 1] + a[i, 2] * a[j, 2]
                            r[3 + i, 3 + j] = rv_scaled * aat
                        r[3 + i, 3 + i] += rr_scaled
                        for l in range(9):
                            h[3 + i, 6 + l] = -aom[i, l] * d_er[6 + l]
                ok, nis, logdet = update_one(x, p, nu, h, r, s_keep, ws)
                if not ok:
                    bad = True
                else:
                    updated_rate = use_rate and correlated
                    # log det S in SI = log det S̃ + 2 Σ log(measurement scale)
                    scale_logdet = 6.0 * np.log(e_a)
                    if use_rate:
                        scale_logdet += 6.0 * np.log(e_r)
                    # the leading 3×3 block of chol(S) is chol(S_aa): the attitude NIS is free
                    chol = ws[4]
                    for i in range(3):
                        v = nu[i]
                        for c in range(i):
                            v -= chol[i, c] * y3[c]
                        y3[i] = v / chol[i, i]
                    rec_stats[bi, k, 0] = y3[0] ** 2 + y3[1] ** 2 + y3[2] ** 2
                    rec_stats[bi, k, 1] = _nis_block(s_keep, nu, 3, s3, y3) if use_rate else np.nan
                    rec_stats[bi, k, 2] = nis
                    rec_stats[bi, k, 3] = logdet + scale_logdet
                    rec_stats[bi, k, 4] = (s_keep[0, 0] + s_keep[1, 1] + s_keep[2, 2]) * e_a**2
                    # reset: Ĉ ← Ĉ Exp(δθ), b̂ += Δb, p̂ += Δp
                    for i in range(15):
                        x[i] *= d[i]
                    quat_from_rotvec(x[0:3], qinc)
                    quat_mul(q_hat[bi], qinc, qtmp)
                    _normalize(qtmp)
                    for i in range(4):
                        q_hat[bi, i] = qtmp[i]
                    for i in range(3):
                        b_hat[bi, i] += x[3 + i]
                    for i in range(9):
                        p_hat[bi, i] += x[6 + i]
                    bad = not _rate(gyro[bi, k], b_hat[bi], p_hat[bi], a, w)
            for i in range(15):
                rec_dx[bi, k, i] = x[i]
            # ---- record the a-posteriori estimate ----------------------------------------
            for i in range(4):
                rec_est[bi, k, i] = q_hat[bi, i]
            for i in range(3):
                rec_est[bi, k, 4 + i] = b_hat[bi, i]
                rec_rate[bi, k, i] = w[i]
            for i in range(9):
                rec_est[bi, k, 7 + i] = p_hat[bi, i]
            for i in range(15):
                rec_var[bi, k, i] = p[i, i] * d[i] * d[i]
                if not (np.isfinite(p[i, i]) and p[i, i] > 0.0):
                    bad = True
            if full_cov:
                for i in range(15):
                    for j in range(15):
                        rec_cov[bi, k, i, j] = p[i, j] * (d[i] * d[j])
            if bad:
                diverged[bi] = True
                continue
            # ---- propagate: Ĉ ← Ĉ Exp(ω̂ Δt), P̃ ← Φ̃ P̃ Φ̃ᵀ + Q̃d --------------------------
            for i in range(3):
                vec[i] = w[i] * dt
            quat_from_rotvec(vec, qinc)
            quat_mul(q_hat[bi], qinc, qtmp)
            _normalize(qtmp)
            for i in range(4):
                q_hat[bi, i] = qtmp[i]
            for l in range(9):
                q_c[l] = kappa[bi, k, l] * qp0
            _a_omega(a, w, aom)
            for i in range(3):
                vec[i] = -w[i]
            _skew_sq(vec, wx, wx2)
            w2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
            rate = np.sqrt(w2)
            _transition(wx, wx2, rate, dt, rr, gg)
            if updated_rate:
                # C̃ = E[w̃_θ ṽ_rᵀ] = Γ A (σ_v²/Δt) Aᵀ, scaled by d_θ and e_r
                for i in range(3):
                    for j in range(3):
                        v = 0.0
                        for c in range(3):
                            v += gg[i, c] * (
                                a[j, 0] * a[c, 0] + a[j, 1] * a[c, 1] + a[j, 2] * a[c, 2]
                            )
                        c_tr[i, j] = v * corr_scale[i]
            for i in range(3):
                for j in range(3):
                    phi_top[i, j] = rr[i, j] * ratio[i, j]
                    v = 0.0
                    for c in range(3):
                        v += gg[i, c] * a[c, j]
                    phi_top[i, 3 + j] = -v * ratio[i, 3 + j]
                for l in range(9):
                    v = 0.0
                    for c in range(3):
                        v += gg[i, c] * aom[c, l]
                    phi_top[i, 6 + l] = -v * ratio[i, 6 + l]
            # T = Φ̃_top P̃ (3×15)
            for i in range(3):
                for j in range(15):
                    t_mat[i, j] = 0.0
                for c in range(15):
                    coef = phi_top[i, c]
                    for j in range(15):
                        t_mat[i, j] += coef * p[c, j]
            # M1 = σ_v² A Aᵀ, M2 = A (σ_u² I + Ω diag(q) Ωᵀ) Aᵀ; Ω diag(q) Ωᵀ is diagonal
            # because each column of Ω has a single non-zero
            for r_ in range(3):
                dq[r_] = sigma_u**2
            for l in range(9):
                dq[_OM_ROW[l]] += q_c[l] * w[_OM_COL[l]] ** 2
            for i in range(3):
                for j in range(3):
                    aat = a[i, 0] * a[j, 0] + a[i, 1] * a[j, 1] + a[i, 2] * a[j, 2]
                    m1[i, j] = sigma_v**2 * aat
                    m2[i, j] = (
                        a[i, 0] * dq[0] * a[j, 0]
                        + a[i, 1] * dq[1] * a[j, 1]
                        + (a[i, 2] * dq[2] * a[j, 2])
                    )
                    q_tt[i, j] = 0.0
                    g_int[i, j] = 0.0
            n_nodes = _nodes_needed(rate * dt, max_nodes)
            for nd in range(n_nodes):
                s_j = gl_s[n_nodes - 2, nd] * dt
                w_j = gl_w[n_nodes - 2, nd] * dt
                _transition(wx, wx2, rate, s_j, rr, gg)
                for i in range(3):
                    for j in range(3):
                        v1 = 0.0
                        v2 = 0.0
                        for c in range(3):
                            v1 += rr[i, c] * m1[c, j]
                            v2 += gg[i, c] * m2[c, j]
                        tmp[i, j] = v1
                        gm2[i, j] = v2
                for i in range(3):
                    for j in range(3):
                        v = 0.0
                        for c in range(3):
                            v += tmp[i, c] * rr[j, c] + gm2[i, c] * gg[j, c]
                        q_tt[i, j] += w_j * v
                        g_int[i, j] += w_j * gg[i, j]
            # P̃ ← Φ̃ P̃ Φ̃ᵀ: rows/cols 0..2 change, the rest stays
            for i in range(3):
                for j in range(3):
                    v = 0.0
                    for c in range(15):
                        v += t_mat[i, c] * phi_top[j, c]
                    tmp[i, j] = v
            for i in range(3):
                for j in range(3, 15):
                    p[i, j] = t_mat[i, j]
                    p[j, i] = t_mat[i, j]
            for i in range(3):
                for j in range(3):
                    p[i, j] = (
                        0.5 * (tmp[i, j] + tmp[j, i])
                        + 0.5 * (q_tt[i, j] + q_tt[j, i]) * inv_dd[i, j]
                    )
            # + Q̃d off-diagonal attitude blocks and the random-walk diagonals
            for i in range(3):
                for j in range(3):
                    v = 0.0
                    for c in range(3):
                        v += g_int[i, c] * a[c, j]
                    qtb = -(sigma_u**2) * v * inv_dd[i, 3 + j]
                    p[i, 3 + j] += qtb
                    p[3 + j, i] += qtb
                for l in range(9):
                    v = 0.0
                    for c in range(3):
                        v += g_int[i, c] * aom[c, l]
                    qtp = -q_c[l] * v * inv_dd[i, 6 + l]
                    p[i, 6 + l] += qtp
                    p[6 + l, i] += qtp
            for i in range(3):
                p[3 + i, 3 + i] += sigma_u**2 * dt * inv_d2[3 + i]
            for i in range(9):
                p[6 + i, 6 + i] += q_c[i] * dt * inv_d2[6 + i]
            if updated_rate:
                _correlation_correction(
                    p, q_hat[bi], ws, c_tr, phi_top, w_corr, sinv_rr, qinc, qtmp, vec, d, tmp
                )
