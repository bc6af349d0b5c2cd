r"""Batch least-squares gyro calibration (``batch``): the offline counterpart of the filter
(docs/methods.md, "Batch least squares").

Unknowns, one set per trial and constant over the run::

    y = [α (3), b (3), p (9)]      Ĉ_0 = C_ADS,0 Exp(α),   b: gyro bias at t = 0,   p: calibration

Given ``y`` the gyro is integrated over the whole run, ``ω̂_k = A (ω̃_k − b)``,
``A = (I + K(p))⁻¹``, ``Ĉ_{k+1} = Ĉ_k Exp(ω̂_k Δt)``. The residuals are the attitude difference
``z_a,k = Log(Ĉ_kᵀ C_ADS,k)`` and (with rate matching) ``z_r,k = ω_ADS,k − ω̂_k``. Their Jacobian
with respect to ``y`` follows from the sensitivity of the propagated attitude,
``Ĉ_k(y + dy) = Ĉ_k(y) Exp(S_k dy)``, propagated along the trajectory::

    S_0 = [J_r(α), 0, 0],   S_{k+1} = R_k S_k + [0, −Γ_k A, −Γ_k A Ω(ω̂_k)]
    R_k = Exp(−ω̂_k Δt),     Γ_k = Δt J_r(ω̂_k Δt)
    z_a,k ≈ S_k dy + ξ_k + ν_a,k
    z_r,k ≈ [0, −A, −A Ω(ω̂_k)] dy − A β_k − A η_k + ν_r,k

The gyro's angle and rate random walks make the residuals coloured: the attitude carries the
integrated gyro noise ``ξ``, the bias drifts by ``β`` from its value at t = 0, and the gyro noise
``η_k`` of the rate residual is the one that drives ``ξ`` over the next step::

    ξ_{k+1} = R_k ξ_k − Γ_k A β_k − Γ_k A η_k,    β_{k+1} = β_k + u_k,    ξ_0 = β_0 = 0

Weighting the residuals as white would count that noise twice (the estimate stays unbiased but
is far from the bound, and its covariance is wrong). The normal equations are therefore formed
from residuals whitened by a Kalman filter over the six nuisance states ``n = [ξ, β]`` (with the
correlated-noise prediction of the transfer-alignment filter), run on the residual column and
the fifteen Jacobian columns at once: with innovations ``ν_k`` and their covariance ``S_k``,

    N = P_y0⁻¹ + Σ_k ν_{H,k}ᵀ S_k⁻¹ ν_{H,k},   n = Σ_k ν_{H,k}ᵀ S_k⁻¹ ν_{z,k} − P_y0⁻¹ y

which is generalised least squares with the exact covariance of the stacked residuals. The
prior ``P_y0 = diag(filter.initial_sigma²)`` enters as a pseudo-observation. Gauss–Newton:
``y ← y + N⁻¹ n``, re-propagate, repeat until every component of the step is below
:data:`STEP_TOLERANCE` times its standard deviation (usually three passes).

Reported per epoch: ``p̂`` (constant), ``b̂_k = b̂ + β̂_k`` and ``Ĉ_k Exp(ξ̂_k)`` with the
nuisance smoothed over the whole run (modified Bryson–Frazier backward pass). Covariance at the
sampled epochs: ``M_k P_y M_kᵀ + P^n_{k|N}`` (the smoothing error is orthogonal to all
innovations, hence to the error of ``ŷ``), ``M_k`` mapping ``dy`` to the error state through
``S_k`` and the smoothed Jacobian columns.

Everything runs per trial in one compiled kernel (trials in parallel), in units scaled by the
prior sigmas (``y``) and by the measurement sigmas (rows and nuisance states).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from qkf.core.kalman import (
    backward_solve_t,
    cholesky_inplace,
    forward_solve,
    symmetrize_inplace,
)
from qkf.core.quat import normalize, quat_from_rotvec, quat_mul, rotvec_from_quat
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import ScenarioData

MAX_ITERATIONS = 10
"""Gauss–Newton passes at most (re-propagation each)."""
STEP_TOLERANCE = 1e-2
"""Converged when every component of the step is below this fraction of its 1-σ."""

_FASTMATH = {"reassoc", "contract", "arcp"}
_N_Y = 15  # unknowns α, b, p
_N_C = 16  # columns: residual + 15 Jacobian columns


# --- small SO(3) helpers ------------------------------------------------------------------------


@nb.njit(cache=True, fastmath=_FASTMATH)
def _rodrigues(theta: float) -> tuple[float, float, float]:
    """``sin θ/θ``, ``(1 − cos θ)/θ²``, ``(θ − sin θ)/θ³`` (series below 0.1 rad)."""
    t2 = theta * theta
    if theta < 0.1:
        a = 1.0 - t2 / 6.0 + t2**2 / 120.0 - t2**3 / 5040.0 + t2**4 / 362880.0
        b = 0.5 - t2 / 24.0 + t2**2 / 720.0 - t2**3 / 40320.0 + t2**4 / 3628800.0
        c = 1.0 / 6.0 - t2 / 120.0 + t2**2 / 5040.0 - t2**3 / 362880.0 + t2**4 / 39916800.0
        return a, b, c
    return np.sin(theta) / theta, (1.0 - np.cos(theta)) / t2, (theta - np.sin(theta)) / (t2 * theta)


@nb.njit(cache=True, fastmath=_FASTMATH)
def _exp_and_jac(phi: np.ndarray, rot: np.ndarray, jac: np.ndarray) -> None:
    """``rot = Exp(φ) = I + a[φ×] + b[φ×]²`` and ``jac = J_l(φ) = I + b[φ×] + c[φ×]²``, using
    ``[φ×]² = φφᵀ − θ² I``."""
    theta = np.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    a, b, c = _rodrigues(theta)
    t2 = theta * theta
    for i in range(3):
        for j in range(3):
            pp = phi[i] * phi[j]
            rot[i, j] = b * pp
            jac[i, j] = c * pp
        rot[i, i] += 1.0 - b * t2
        jac[i, i] += 1.0 - c * t2
    # skew part: [φ×] = [[0, −φz, φy], [φz, 0, −φx], [−φy, φx, 0]]
    rot[0, 1] -= a * phi[2]
    rot[0, 2] += a * phi[1]
    rot[1, 0] += a * phi[2]
    rot[1, 2] -= a * phi[0]
    rot[2, 0] -= a * phi[1]
    rot[2, 1] += a * phi[0]
    jac[0, 1] -= b * phi[2]
    jac[0, 2] += b * phi[1]
    jac[1, 0] += b * phi[2]
    jac[1, 2] -= b * phi[0]
    jac[2, 0] -= b * phi[1]
    jac[2, 1] += b * phi[0]


@nb.njit(cache=True, fastmath=_FASTMATH)
def _rate_matrix(p: np.ndarray, a: np.ndarray) -> bool:
    """``A = (I + K(p))⁻¹`` (3×3) into ``a``; False if ``I + K`` is (nearly) singular."""
    m = np.empty((3, 3))
    m[0, 0], m[0, 1], m[0, 2] = 1.0 + p[0], p[3], p[4]
    m[1, 0], m[1, 1], m[1, 2] = p[6], 1.0 + p[1], p[5]
    m[2, 0], m[2, 1], m[2, 2] = p[7], p[8], 1.0 + p[2]
    det = (
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )
    if not np.abs(det) > 1e-12:
        return False
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            # adjugate: A_ji = cofactor_ij / det
            a[j, i] = (m[i1, j1] * m[i2, j2] - m[i1, j2] * m[i2, j1]) / det
    return True


@nb.njit(cache=True, fastmath=_FASTMATH)
def _rate_jacobian(a: np.ndarray, w: np.ndarray, out: np.ndarray) -> None:
    """``out`` (3×15) = ``[0, −A, −A Ω(ω)]``: derivative of ``ω̂`` with respect to ``y``."""
    # Ω(ω) columns: s_x s_y s_z k_xy k_xz k_yz k_yx k_zx k_zy
    om_row = (0, 1, 2, 0, 0, 1, 1, 2, 2)
    om_col = (0, 1, 2, 1, 2, 2, 0, 0, 1)
    for i in range(3):
        for j in range(3):
            out[i, j] = 0.0
            out[i, 3 + j] = -a[i, j]
        for col in range(9):
            out[i, 6 + col] = -a[i, om_row[col]] * w[om_col[col]]


# Small dense products with sizes read at run time: constant trip counts would let LLVM unroll
# every loop nest in full, which made the kernel take minutes to compile. ``out`` never aliases
# an input. Inner loops run along rows (axpy form), which vectorises.


@nb.njit(cache=True, fastmath=_FASTMATH)
def _mm(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a b``."""
    out[:] = 0.0
    _mm_add(a, b, out)


@nb.njit(cache=True, fastmath=_FASTMATH)
def _mm_add(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out += a b``."""
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            aic = a[i, c]
            if aic != 0.0:
                for j in range(b.shape[1]):
                    out[i, j] += aic * b[c, j]


@nb.njit(cache=True, fastmath=_FASTMATH)
def _tm_add(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out += aᵀ b``."""
    for c in range(a.shape[0]):
        for i in range(a.shape[1]):
            aci = a[c, i]
            if aci != 0.0:
                for j in range(b.shape[1]):
                    out[i, j] += aci * b[c, j]


@nb.njit(cache=True, fastmath=_FASTMATH)
def _mt(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a bᵀ``."""
    for i in range(a.shape[0]):
        for j in range(b.shape[0]):
            v = 0.0
            for c in range(a.shape[1]):
                v += a[i, c] * b[j, c]
            out[i, j] = v


@nb.njit(cache=True, fastmath=_FASTMATH)
def _inverse_spd(mat: np.ndarray, out: np.ndarray) -> bool:
    """``out = mat⁻¹`` of a symmetric positive-definite matrix (``mat`` is overwritten by its
    Cholesky factor); False if it is not positive definite."""
    n = mat.shape[0]
    if not cholesky_inplace(mat):
        return False
    col = np.empty(n)
    for j in range(n):
        col[:] = 0.0
        col[j] = 1.0
        forward_solve(mat, col)
        backward_solve_t(mat, col)
        for i in range(n):
            out[i, j] = col[i]
    return True


# --- one trial ----------------------------------------------------------------------------------


@nb.njit(cache=True, fastmath=_FASTMATH)
def propagate_sensitivity(
    gyro: np.ndarray, q_start: np.ndarray, y: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro-propagated attitude of one trial and its sensitivity to ``y = [α, b, p]`` (SI).

    ``gyro`` (N, 3) rad/s, ``q_start`` the attitude ``Ĉ_0`` is taken relative to (scalar-last),
    ``dt`` s. Returns quaternions ``q`` (N, 4) of ``Ĉ_k``, rates ``ω̂`` (N, 3) and ``S`` (N, 3, 15)
    with ``Ĉ_k(y + dy) ≈ Ĉ_k(y) Exp(S_k dy)``.
    """
    n = gyro.shape[0]
    q = np.empty((n, 4))
    w = np.empty((n, 3))
    sens = np.empty((n, 3, _N_Y))
    a = np.empty((3, 3))
    if not _rate_matrix(y[6:15], a):
        q[:] = np.nan
        w[:] = np.nan
        sens[:] = np.nan
        return q, w, sens
    rot = np.empty((3, 3))
    jac = np.empty((3, 3))
    dq = np.empty(4)
    s = np.zeros((3, _N_Y))
    g = np.empty((3, _N_Y))
    phi = np.empty(3)
    for i in range(3):
        phi[i] = -y[i]
    _exp_and_jac(phi, rot, jac)  # J_r(α) = J_l(−α)
    for i in range(3):
        for j in range(3):
            s[i, j] = jac[i, j]
    quat_from_rotvec(y[0:3], dq)
    quat_mul(q_start, dq, q[0])
    normalize(q[0])
    for k in range(n):
        for i in range(3):
            w[k, i] = 0.0
            for j in range(3):
                w[k, i] += a[i, j] * (gyro[k, j] - y[3 + j])
        sens[k] = s
        if k == n - 1:
            break
        for i in range(3):
            phi[i] = -w[k, i] * dt
        _exp_and_jac(phi, rot, jac)  # R = Exp(−ω̂Δt), Γ = Δt J_l(−ω̂Δt)
        _rate_jacobian(a, w[k], g)
        _step_sensitivity(s, rot, jac, g, dt)
        for i in range(3):
            phi[i] = w[k, i] * dt
        quat_from_rotvec(phi, dq)
        quat_mul(q[k], dq, q[k + 1])
        normalize(q[k + 1])
    return q, w, sens


@nb.njit(cache=True, fastmath=_FASTMATH)
def _step_sensitivity(
    s: np.ndarray, rot: np.ndarray, jac: np.ndarray, g: np.ndarray, dt: float
) -> None:
    """``S ← R S + Γ ∂ω̂/∂y`` in place (``g`` = ∂ω̂/∂y, ``Γ = Δt jac``)."""
    tmp = np.zeros(s.shape)
    _mm_add(rot, s, tmp)
    gam = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            gam[i, j] = dt * jac[i, j]
    _mm_add(gam, g, tmp)
    s[:] = tmp


@nb.njit(cache=True, fastmath=_FASTMATH)
def _solve_normal(g: np.ndarray, y_scaled: np.ndarray, step: np.ndarray, cov: np.ndarray) -> bool:
    """Scaled normal equations ``(G_HH + I) dỹ = G_Hz − ỹ``; ``cov`` = (G_HH + I)⁻¹."""
    ny = y_scaled.shape[0]
    nmat = np.empty((ny, ny))
    for i in range(ny):
        for j in range(ny):
            nmat[i, j] = 0.5 * (g[1 + i, 1 + j] + g[1 + j, 1 + i])
        nmat[i, i] += 1.0
    if not _inverse_spd(nmat, cov):
        return False
    for i in range(ny):
        v = 0.0
        for j in range(ny):
            v += cov[i, j] * (g[1 + j, 0] - y_scaled[j])
        step[i] = v
    return True


@nb.njit(cache=True, fastmath=_FASTMATH)
def _trial(
    gyro: np.ndarray,
    ads_q: np.ndarray,
    ads_rate: np.ndarray,
    meas: np.ndarray,
    slot: np.ndarray,
    consts: np.ndarray,
    d: np.ndarray,
    use_rate: bool,
    max_iter: int,
    tol: float,
    est: np.ndarray,
    cov_out: np.ndarray,
    info: np.ndarray,
    y_out: np.ndarray,
    cov_y_out: np.ndarray,
    step_out: np.ndarray,
) -> None:
    """Gauss–Newton passes and the smoothing pass of one trial (see the module docstring).

    ``consts`` = [Δt, σ_a, σ_r, σ_v, σ_u] (SI); ``slot[k]`` the index of epoch k among the
    sampled covariance epochs (−1 if none). ``info`` = [passes, converged, χ², rows].
    """
    n = gyro.shape[0]
    m = 6 if use_rate else 3
    dt, sa, sr, sv, su = consts[0], consts[1], consts[2], consts[3], consts[4]
    er = np.sqrt(sr * sr + sv * sv / dt)
    n_slot = cov_out.shape[0]

    # storage of the last forward pass, for the backward pass
    q = np.empty((n, 4))
    sens_s = np.empty((max(n_slot, 1), 3, _N_Y))
    xz = np.empty((n, 6))
    pplus = np.empty((n, 6, 6))
    nu_all = np.zeros((n, m, _N_C))
    sinv_all = np.zeros((n, m, m))
    gain_all = np.zeros((n, 6, m))
    fbar_all = np.empty((n, 6, 6))
    xs = np.empty((max(n_slot, 1), 6, _N_C))

    y = np.zeros(_N_Y)
    y_scaled = np.zeros(_N_Y)
    step = np.zeros(_N_Y)
    cov_y = np.zeros((_N_Y, _N_Y))
    g = np.zeros((_N_C, _N_C))
    hn = np.zeros((m, 6))  # nuisance measurement matrix (scaled)
    r_t = np.zeros((m, m))  # measurement noise (scaled)
    a = np.empty((3, 3))
    ok = True
    converged = False
    passes = 0
    rows = 0
    for it in range(max_iter):
        passes = it + 1
        if not _rate_matrix(y[6:15], a):
            ok = False
            break
        rows = _forward(
            gyro,
            ads_q,
            ads_rate,
            meas,
            slot,
            y,
            a,
            dt,
            sa,
            er,
            sr,
            sv,
            su,
            d,
            use_rate,
            q,
            sens_s,
            xz,
            pplus,
            nu_all,
            sinv_all,
            gain_all,
            fbar_all,
            xs,
            g,
            hn,
            r_t,
        )
        if rows < 0:
            ok = False
            break
        for i in range(_N_Y):
            y_scaled[i] = y[i] / d[i]
        if not _solve_normal(g, y_scaled, step, cov_y):
            ok = False
            break
        worst = 0.0
        for i in range(_N_Y):
            worst = max(worst, np.abs(step[i]) / np.sqrt(cov_y[i, i]))
        if not np.isfinite(worst):
            ok = False
            break
        if worst < tol:
            converged = True
            break
        if it == max_iter - 1:
            break
        for i in range(_N_Y):
            y[i] += step[i] * d[i]
    info[0] = passes
    info[1] = 1.0 if converged else 0.0
    info[2] = g[0, 0]
    info[3] = rows
    if not ok:
        est[:] = np.nan
        cov_out[:] = np.nan
        y_out[:] = np.nan
        cov_y_out[:] = np.nan
        step_out[:] = np.nan
        return
    for i in range(_N_Y):
        y_out[i] = y[i]
        step_out[i] = step[i] * d[i]
        for j in range(_N_Y):
            cov_y_out[i, j] = cov_y[i, j] * d[i] * d[j]
    _backward(
        q,
        sens_s,
        xz,
        pplus,
        nu_all,
        sinv_all,
        gain_all,
        fbar_all,
        xs,
        meas,
        slot,
        hn,
        y,
        cov_y_out,
        d,
        sa,
        er,
        est,
        cov_out,
    )


@nb.njit(cache=True, fastmath=_FASTMATH)
def _forward(
    gyro: np.ndarray,
    ads_q: np.ndarray,
    ads_rate: np.ndarray,
    meas: np.ndarray,
    slot: np.ndarray,
    y: np.ndarray,
    a: np.ndarray,
    dt: float,
    sa: float,
    er: float,
    sr: float,
    sv: float,
    su: float,
    d: np.ndarray,
    use_rate: bool,
    q: np.ndarray,
    sens_s: np.ndarray,
    xz: np.ndarray,
    pplus: np.ndarray,
    nu_all: np.ndarray,
    sinv_all: np.ndarray,
    gain_all: np.ndarray,
    fbar_all: np.ndarray,
    xs: np.ndarray,
    g: np.ndarray,
    hn: np.ndarray,
    r_t: np.ndarray,
) -> int:
    """One pass at ``y``: propagate, form the columns, run the nuisance filter, accumulate
    ``G = Σ νᵀ S⁻¹ ν`` (16×16). Returns the number of measurement rows (−1 on failure)."""
    n = gyro.shape[0]
    m = hn.shape[0]
    nx = pplus.shape[1]  # 6 nuisance states
    nc = g.shape[0]  # 16 columns
    ny = nc - 1
    sv2dt = sv * sv / dt
    # scaled nuisance model: state [ξ/σ_a, β/e_r], rows [z_a/σ_a, z_r/e_r]
    hn[:] = 0.0
    r_t[:] = 0.0
    for i in range(3):
        hn[i, i] = 1.0
        r_t[i, i] = 1.0
    rr_inv = np.zeros((3, 3))  # R̃_r⁻¹
    if m == 6:
        rr = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                hn[3 + i, 3 + j] = -a[i, j]
                v = 0.0
                for c in range(3):
                    v += a[i, c] * a[j, c]
                rr[i, j] = sv2dt * v / (er * er)
            rr[i, i] += sr * sr / (er * er)
        for i in range(3):
            for j in range(3):
                r_t[3 + i, 3 + j] = rr[i, j]
        if not _inverse_spd(rr, rr_inv):
            return -1

    x = np.zeros((nx, nc))
    p = np.zeros((nx, nx))
    g[:] = 0.0
    s = np.zeros((3, ny))
    zc = np.empty((m, nc))
    nu = np.empty((m, nc))
    wm = np.empty((m, nc))
    smat = np.empty((m, m))
    sinv = np.empty((m, m))
    ut = np.empty((m, nx))  # (P H̃ᵀ)ᵀ
    kt = np.empty((m, nx))  # Kᵀ
    rk = np.empty((m, nx))
    ikh = np.empty((nx, nx))
    t1 = np.empty((nx, nx))
    tmpx = np.empty((nx, nc))
    fbar = np.empty((nx, nx))
    qbar = np.empty((nx, nx))
    ctr = np.empty((3, 3))  # C̃_θr
    cr = np.empty((3, 3))  # C̃_θr R̃_r⁻¹
    ga = np.empty((3, 3))  # Γ A
    hr = np.empty((3, ny))
    rot = np.empty((3, 3))
    jac = np.empty((3, 3))
    phi = np.empty(3)
    dq = np.empty(4)
    qc = np.empty(4)
    rel = np.empty(4)
    za = np.empty(3)
    w = np.empty(3)

    # initial attitude Ĉ_0 = C_ADS,0 Exp(α) and sensitivity S_0 = [J_r(α), 0, 0]
    for i in range(3):
        phi[i] = -y[i]
    _exp_and_jac(phi, rot, jac)
    for i in range(3):
        for j in range(3):
            s[i, j] = jac[i, j]
    quat_from_rotvec(y[0:3], dq)
    quat_mul(ads_q[0], dq, q[0])
    normalize(q[0])

    rows = 0
    for k in range(n):
        for i in range(3):
            v = 0.0
            for j in range(3):
                v += a[i, j] * (gyro[k, j] - y[3 + j])
            w[i] = v
        _rate_jacobian(a, w, hr)
        # columns [residual | Jacobian · diag(d)], each row divided by its sigma
        qc[0], qc[1], qc[2], qc[3] = -q[k, 0], -q[k, 1], -q[k, 2], q[k, 3]
        quat_mul(qc, ads_q[k], rel)
        rotvec_from_quat(rel, za)
        for i in range(3):
            zc[i, 0] = za[i] / sa
            for j in range(ny):
                zc[i, 1 + j] = s[i, j] * d[j] / sa
        if m == 6:
            for i in range(3):
                zc[3 + i, 0] = (ads_rate[k, i] - w[i]) / er
                for j in range(ny):
                    zc[3 + i, 1 + j] = hr[i, j] * d[j] / er
        if slot[k] >= 0:
            sens_s[slot[k]] = s

        updated = meas[k]
        if updated:
            rows += m
            _mm(hn, x, nu)  # ν = Z − H̃ X
            for i in range(m):
                for j in range(nc):
                    nu[i, j] = zc[i, j] - nu[i, j]
            _mm(hn, p, ut)  # Uᵀ = H̃ P
            _mt(ut, hn, smat)  # S = H̃ P H̃ᵀ + R̃
            for i in range(m):
                for j in range(m):
                    smat[i, j] += r_t[i, j]
            symmetrize_inplace(smat)
            if not _inverse_spd(smat, sinv):
                return -1
            _mm(sinv, ut, kt)  # Kᵀ = S⁻¹ Uᵀ
            _mm(sinv, nu, wm)  # S⁻¹ ν
            _tm_add(nu, wm, g)  # G += νᵀ S⁻¹ ν
            nu_all[k] = nu
            sinv_all[k] = sinv
            for i in range(nx):
                for j in range(m):
                    gain_all[k, i, j] = kt[j, i]
            _tm_add(kt, nu, x)  # X += K ν
            # P ← (I − K H̃) P (I − K H̃)ᵀ + K R̃ Kᵀ
            ikh[:] = 0.0
            _tm_add(kt, hn, ikh)
            for i in range(nx):
                for j in range(nx):
                    ikh[i, j] = (1.0 if i == j else 0.0) - ikh[i, j]
            _mm(ikh, p, t1)
            _mt(t1, ikh, p)
            _mm(r_t, kt, rk)
            _tm_add(kt, rk, p)
            symmetrize_inplace(p)
        for i in range(nx):
            xz[k, i] = x[i, 0]
        pplus[k] = p
        if slot[k] >= 0:
            xs[slot[k]] = x
        if k == n - 1:
            break

        # prediction to k+1, decorrelated: F̄ = F − C̃ R̃⁻¹ H̃, Q̄ = Q̃ − C̃ R̃⁻¹ C̃ᵀ, + C̃ R̃⁻¹ Z
        for i in range(3):
            phi[i] = -w[i] * dt
        _exp_and_jac(phi, rot, jac)  # R = Exp(−ω̂Δt), Γ = Δt J_l(−ω̂Δt)
        _mm(jac, a, ga)
        for i in range(3):
            for j in range(3):
                ga[i, j] *= dt
        fbar[:] = 0.0
        qbar[:] = 0.0
        _mt(ga, ga, t1)
        for i in range(3):
            for j in range(3):
                fbar[i, j] = rot[i, j]
                fbar[i, 3 + j] = -ga[i, j] * er / sa
                qbar[i, j] = sv2dt * t1[i, j] / (sa * sa)
            fbar[3 + i, 3 + i] = 1.0
            qbar[3 + i, 3 + i] = su * su * dt / (er * er)
        correlated = updated and m == 6
        if correlated:
            _mt(ga, a, ctr)  # C̃_θr = Γ A Aᵀ σ_v²/Δt / (σ_a e_r)
            for i in range(3):
                for j in range(3):
                    ctr[i, j] *= sv2dt / (sa * er)
            _mm(ctr, rr_inv, cr)
            _mm(cr, a, rot)  # −C̃ R̃⁻¹ H̃_r with H̃_r = [0, −A]  (rot reused as scratch)
            _mt(cr, ctr, jac)  # C̃ R̃⁻¹ C̃ᵀ  (jac reused as scratch)
            for i in range(3):
                for j in range(3):
                    fbar[i, 3 + j] += rot[i, j]
                    qbar[i, j] -= jac[i, j]
        _mm(fbar, x, tmpx)
        if correlated:
            for i in range(3):
                for j in range(nc):
                    v = 0.0
                    for c in range(3):
                        v += cr[i, c] * zc[3 + c, j]
                    tmpx[i, j] += v
        x[:] = tmpx
        _mm(fbar, p, t1)
        _mt(t1, fbar, p)
        for i in range(nx):
            for j in range(nx):
                p[i, j] += qbar[i, j]
        symmetrize_inplace(p)
        fbar_all[k] = fbar

        # attitude and sensitivity to k+1 (rot and jac recomputed: reused above)
        for i in range(3):
            phi[i] = -w[i] * dt
        _exp_and_jac(phi, rot, jac)
        _step_sensitivity(s, rot, jac, hr, dt)
        for i in range(3):
            phi[i] = w[i] * dt
        quat_from_rotvec(phi, dq)
        quat_mul(q[k], dq, q[k + 1])
        normalize(q[k + 1])
    return rows


@nb.njit(cache=True, fastmath=_FASTMATH)
def _backward(
    q: np.ndarray,
    sens_s: np.ndarray,
    xz: np.ndarray,
    pplus: np.ndarray,
    nu_all: np.ndarray,
    sinv_all: np.ndarray,
    gain_all: np.ndarray,
    fbar_all: np.ndarray,
    xs: np.ndarray,
    meas: np.ndarray,
    slot: np.ndarray,
    hn: np.ndarray,
    y: np.ndarray,
    cov_y: np.ndarray,
    d: np.ndarray,
    sa: float,
    er: float,
    est: np.ndarray,
    cov_out: np.ndarray,
) -> None:
    """Modified Bryson–Frazier smoothing of the nuisance and the reported estimates.

    With the adjoint ``λ⁺_k`` (6×16) and ``Λ⁺_k`` (6×6) after the update of epoch k:
    ``x_{k|N} = x⁺_k + P⁺_k λ⁺_k``, ``P_{k|N} = P⁺_k − P⁺_k Λ⁺_k P⁺_k``; backwards,
    ``λ⁻ = H̃ᵀ S⁻¹ ν + (I − K H̃)ᵀ λ⁺``, ``Λ⁻ = H̃ᵀ S⁻¹ H̃ + (I − K H̃)ᵀ Λ⁺ (I − K H̃)``,
    ``λ⁺_{k−1} = F̄ᵀ λ⁻``, ``Λ⁺_{k−1} = F̄ᵀ Λ⁻ F̄``.
    """
    n = q.shape[0]
    m = hn.shape[0]
    nx = pplus.shape[1]
    nc = nu_all.shape[2]
    ny = nc - 1
    lam = np.zeros((nx, nc))
    big = np.zeros((nx, nx))
    lam_m = np.empty((nx, nc))
    big_m = np.empty((nx, nx))
    ikh = np.empty((nx, nx))
    hts = np.empty((m, nx))  # S⁻¹ H̃  (= (H̃ᵀ S⁻¹)ᵀ)
    t1 = np.empty((nx, nx))
    xsm = np.empty((nx, nc))
    psm = np.empty((nx, nx))
    mmat = np.empty((15, ny))
    mp = np.empty((15, ny))
    pk = np.empty((nx, nx))
    fk = np.empty((nx, nx))
    phi = np.empty(3)
    dq = np.empty(4)
    for k in range(n - 1, -1, -1):
        pk[:] = pplus[k]
        # smoothed nuisance of the residual column: the reported estimate
        for i in range(nx):
            v = xz[k, i]
            for c in range(nx):
                v += pk[i, c] * lam[c, 0]
            if i < 3:
                phi[i] = sa * v
            else:
                est[k, 1 + i] = y[i] + er * v  # b̂ + β̂_k (y[3:6] = b̂)
        quat_from_rotvec(phi, dq)
        quat_mul(q[k], dq, est[k, 0:4])
        normalize(est[k, 0:4])
        for i in range(9):
            est[k, 7 + i] = y[6 + i]
        j_slot = slot[k]
        if j_slot >= 0:
            xsm[:] = xs[j_slot]
            _mm_add(pk, lam, xsm)
            _mm(big, pk, t1)  # P_{k|N} = P⁺ − P⁺ Λ P⁺
            _mm(pk, t1, psm)
            for i in range(nx):
                for j in range(nx):
                    psm[i, j] = pk[i, j] - psm[i, j]
            symmetrize_inplace(psm)
            # M: error state per unit dy; δθ = (S − σ_a X̃_ξ/d) dy, δb = (E_b − e_r X̃_β/d) dy
            mmat[:] = 0.0
            for i in range(3):
                for j in range(ny):
                    mmat[i, j] = sens_s[j_slot, i, j] - sa * xsm[i, 1 + j] / d[j]
                    mmat[3 + i, j] = -er * xsm[3 + i, 1 + j] / d[j]
                mmat[3 + i, 3 + i] += 1.0
            for i in range(9):
                mmat[6 + i, 6 + i] = 1.0
            _mm(mmat, cov_y, mp)
            out = cov_out[j_slot]
            _mt(mp, mmat, out)
            for i in range(nx):
                si = sa if i < 3 else er
                for j in range(nx):
                    out[i, j] += si * (sa if j < 3 else er) * psm[i, j]
            symmetrize_inplace(out)
        if k == 0:
            break
        if meas[k]:  # measurement step backwards
            _mm(sinv_all[k], hn, hts)
            ikh[:] = 0.0
            _mm_add(gain_all[k], hn, ikh)
            for i in range(nx):
                for j in range(nx):
                    ikh[i, j] = (1.0 if i == j else 0.0) - ikh[i, j]
            lam_m[:] = 0.0
            _tm_add(hts, nu_all[k], lam_m)  # H̃ᵀ S⁻¹ ν
            _tm_add(ikh, lam, lam_m)  # + (I − K H̃)ᵀ λ
            _mm(big, ikh, t1)
            big_m[:] = 0.0
            _tm_add(ikh, t1, big_m)  # (I − K H̃)ᵀ Λ (I − K H̃)
            _tm_add(hn, hts, big_m)  # + H̃ᵀ S⁻¹ H̃
        else:
            lam_m[:] = lam
            big_m[:] = big
        fk[:] = fbar_all[k - 1]  # time step backwards
        lam[:] = 0.0
        _tm_add(fk, lam_m, lam)
        _mm(big_m, fk, t1)
        big[:] = 0.0
        _tm_add(fk, t1, big)
        symmetrize_inplace(big)


@nb.njit(parallel=True, cache=True, fastmath=_FASTMATH)
def _run_trials(
    gyro: np.ndarray,
    ads_q: np.ndarray,
    ads_rate: np.ndarray,
    meas: np.ndarray,
    slot: np.ndarray,
    consts: np.ndarray,
    d: np.ndarray,
    use_rate: bool,
    max_iter: int,
    tol: float,
    est: np.ndarray,
    cov: np.ndarray,
    info: np.ndarray,
    y_out: np.ndarray,
    cov_y: np.ndarray,
    step_out: np.ndarray,
) -> None:
    for b in nb.prange(gyro.shape[0]):
        _trial(
            gyro[b],
            ads_q[b],
            ads_rate[b],
            meas[b],
            slot,
            consts,
            d,
            use_rate,
            max_iter,
            tol,
            est[b],
            cov[b],
            info[b],
            y_out[b],
            cov_y[b],
            step_out[b],
        )


# --- driver -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchSolution:
    """What the batch estimator found for B trials (SI).

    ``est`` (B, N, 16) and ``cov`` (B, M, 15, 15) as in :class:`MethodOutput`; ``y`` (B, 15) the
    unknowns ``[α, b, p]`` at the reported point, ``cov_y`` their covariance, ``last_step`` the
    Gauss–Newton step computed there (not applied: below ``tolerance`` σ when converged);
    ``passes`` the number of propagations, ``converged``, ``chi2`` the whitened residual sum
    ``Σ νᵀ S⁻¹ ν`` at the reported point and ``rows`` the number of measurement rows.
    """

    est: np.ndarray
    cov: np.ndarray
    y: np.ndarray
    cov_y: np.ndarray
    last_step: np.ndarray
    passes: np.ndarray
    converged: np.ndarray
    chi2: np.ndarray
    rows: np.ndarray


def solve_batch(
    params: FilterParams,
    data: ScenarioData,
    cov_epochs: np.ndarray,
    max_iterations: int = MAX_ITERATIONS,
    tolerance: float = STEP_TOLERANCE,
) -> BatchSolution:
    """Batch least squares on every trial of ``data`` with the noise levels and prior of
    ``params`` (the filter's assumptions; its ``q_p`` is not used: the calibration is constant).

    ``cov_epochs``: epoch indices at which to report the error covariance.
    """
    b, n = data.n_trials, data.n_epochs
    slot = np.full(n, -1, dtype=np.int64)
    slot[np.asarray(cov_epochs, dtype=np.int64)] = np.arange(len(cov_epochs))
    meas = np.ascontiguousarray(np.broadcast_to(np.asarray(data.has_meas, dtype=bool), (b, n)))
    consts = np.array([params.dt, params.sigma_a, params.sigma_r, params.sigma_v, params.sigma_u])
    est = np.empty((b, n, 16))
    cov = np.full((b, len(cov_epochs), 15, 15), np.nan)
    info = np.zeros((b, 4))
    y = np.empty((b, _N_Y))
    cov_y = np.empty((b, _N_Y, _N_Y))
    step = np.empty((b, _N_Y))
    _run_trials(
        np.ascontiguousarray(data.gyro, dtype=float),
        np.ascontiguousarray(data.ads_q, dtype=float),
        np.ascontiguousarray(data.ads_rate, dtype=float),
        meas,
        slot,
        consts,
        np.ascontiguousarray(params.p0_sigma, dtype=float),
        bool(params.use_rate),
        int(max_iterations),
        float(tolerance),
        est,
        cov,
        info,
        y,
        cov_y,
        step,
    )
    return BatchSolution(
        est=est,
        cov=cov,
        y=y,
        cov_y=cov_y,
        last_step=step,
        passes=info[:, 0].astype(np.int64),
        converged=info[:, 1] > 0.5,
        chi2=info[:, 2],
        rows=info[:, 3].astype(np.int64),
    )


def run_batch(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Batch least squares over the whole run (``batch``): constant bias at t = 0 plus its random
    walk, constant calibration, initial attitude; see the module docstring."""
    sol = solve_batch(FilterParams.from_config(cfg), data, covariance_epochs(cfg))
    diverged = ~np.all(np.isfinite(sol.est), axis=(1, 2))
    alive = ~diverged
    notes = {
        "batch": (
            f"offline: whole-run least squares, constant calibration; "
            f"{np.mean(sol.passes[alive]) if alive.any() else float('nan'):.1f} propagations "
            f"per trial on average, {int(np.sum(~sol.converged & alive))} trial(s) not converged "
            f"in {MAX_ITERATIONS}"
        )
    }
    return MethodOutput(
        est=sol.est,
        diverged=diverged,
        kappa=None,
        logs={
            "passes": sol.passes,
            "converged": sol.converged,
            "chi2": sol.chi2,
            "rows": sol.rows,
        },
        notes=notes,
        cov=sol.cov,
    )
