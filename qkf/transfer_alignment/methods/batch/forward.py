r"""One forward pass of the batch estimator at the unknowns ``y`` (compiled).

The gyro is integrated over the whole run (:mod:`.sensitivity`), and every epoch contributes the
residual column and the fifteen Jacobian columns, in units scaled by the prior sigmas ``d`` of
``y`` and the measurement sigmas::

    z_a,k = Log(Ĉ_kᵀ C_ADS,k) / σ_a,          ∂z_a/∂ỹ = S_k D / σ_a
    z_r,k = (ω_ADS,k − ω̂_k) / e_r,             ∂z_r/∂ỹ = [0, −A, −A Ω(ω̂_k)] D / e_r
    e_r = √(σ_r² + σ_v²/Δt)

The coloured part of the residuals (integrated gyro noise ``ξ``, bias walk ``β``) is whitened by a
Kalman filter over the nuisance ``n = [ξ/σ_a, β/e_r]`` run on all 16 columns at once, with the
correlated-noise prediction (the gyro noise of the rate row at k drives ξ over k → k+1), written
in decorrelated form::

    F̄ = F − C̃ R̃_r⁻¹ H̃_r,   Q̄ = Q̃ − C̃ R̃_r⁻¹ C̃ᵀ,   X⁻_{k+1} = F̄ X⁺_k + C̃ R̃_r⁻¹ Z_r,k
    F = [[R, −Γ A e_r/σ_a], [0, I]],   Q̃ = blkdiag(σ_v²/Δt Γ A Aᵀ Γᵀ / σ_a², σ_u² Δt / e_r² I)
    C̃_θr = Γ A Aᵀ (σ_v²/Δt) / (σ_a e_r)

and the whitened innovations accumulate the normal equations ``G = Σ_k ν_kᵀ S_k⁻¹ ν_k``
(16×16: residual and Jacobian columns).
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit
from qkf.core.kalman import symmetrize_inplace
from qkf.core.quat import exp_and_left_jacobian
from qkf.transfer_alignment.methods.batch.dense import inverse_spd, mm, mt, tm_add
from qkf.transfer_alignment.methods.batch.sensitivity import initial_attitude, step_attitude
from qkf.transfer_alignment.methods.batch.structs import (
    Constants,
    Nuisance,
    PassStore,
    TrialData,
)
from qkf.transfer_alignment.model_compiled import attitude_residual, rate_estimate, rate_jacobian


@kernel_jit(nrt=True)
def nuisance_model(
    a: np.ndarray, c: Constants, er: float, nuis: Nuisance, rr_inv: np.ndarray
) -> bool:
    """Fill ``H̃``, ``R̃`` of the nuisance filter and ``R̃_r⁻¹`` (3×3, into ``rr_inv``; zero
    without rate matching); False if ``R̃_r`` is not positive definite.

    ``H̃ = [[I, 0], [0, −A]]``, ``R̃ = blkdiag(I, (σ_v²/Δt A Aᵀ + σ_r² I) / e_r²)``.
    """
    hn, r_t = nuis.hn, nuis.r_t
    m = hn.shape[0]
    sv, sr, dt = c.sigma_v, c.sigma_r, c.dt
    sv2dt = sv * sv / dt
    hn[:] = 0.0
    r_t[:] = 0.0
    for i in range(3):
        hn[i, i] = 1.0
        r_t[i, i] = 1.0
    rr_inv[:] = 0.0
    if m == 6:
        rr = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                hn[3 + i, 3 + j] = -a[i, j]
                v = 0.0
                for k in range(3):
                    v += a[i, k] * a[j, k]
                rr[i, j] = sv2dt * v / (er * er)
            rr[i, i] += sr * sr / (er * er)
        for i in range(3):
            for j in range(3):
                r_t[3 + i, 3 + j] = rr[i, j]
        if not inverse_spd(rr, rr_inv):
            return False
    return True


@kernel_jit(nrt=True)
def forward_pass(
    data: TrialData,
    y: np.ndarray,
    a: np.ndarray,
    c: Constants,
    er: float,
    store: PassStore,
    g: np.ndarray,
    nuis: Nuisance,
) -> int:
    """One pass at ``y`` (SI; ``a`` = A of its calibration): propagate, form the columns, run
    the nuisance filter, accumulate ``G = Σ νᵀ S⁻¹ ν`` (16×16) into ``g`` and keep what the
    smoother needs in ``store``. Returns the number of measurement rows (−1 on failure)."""
    gyro, ads_q, ads_rate, meas, slot = data.gyro, data.ads_q, data.ads_rate, data.meas, data.slot
    q, sens_s, xz, pplus = store.q, store.sens_s, store.xz, store.pplus
    nu_all, sinv_all, gain_all, fbar_all, xs = (
        store.nu_all,
        store.sinv_all,
        store.gain_all,
        store.fbar_all,
        store.xs,
    )
    hn, r_t = nuis.hn, nuis.r_t
    dt, sa, sv, su, d = c.dt, c.sigma_a, c.sigma_v, c.sigma_u, c.d
    n = gyro.shape[0]
    m = hn.shape[0]
    nx = pplus.shape[1]  # 6 nuisance states
    nc = g.shape[0]  # 16 columns
    ny = nc - 1
    sv2dt = sv * sv / dt
    rr_inv = np.empty((3, 3))  # R̃_r⁻¹
    if not nuisance_model(a, c, er, nuis, rr_inv):
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
    hr = np.empty((3, ny))  # ∂ω̂/∂y
    rot = np.empty((3, 3))
    jac = np.empty((3, 3))
    phi = np.empty(3)
    za = np.empty(3)
    w = np.empty(3)

    # initial attitude Ĉ_0 = C_ADS,0 Exp(α) and sensitivity S_0 = [J_r(α), 0, 0]
    initial_attitude(ads_q[0], y, phi, rot, jac, s, q[0])

    rows = 0
    for k in range(n):
        rate_estimate(gyro[k], y[3:6], y[6:15], a, w)  # ω̂_k = A (ω̃_k − b)
        rate_jacobian(a, w, hr)  # ∂ω̂/∂y = [0, −A, −A Ω(ω̂)]
        # columns [residual | Jacobian · diag(d)], each row divided by its sigma
        attitude_residual(q[k], ads_q[k], za)  # z_a = Log(Ĉ_kᵀ C_ADS,k)
        for i in range(3):
            zc[i, 0] = za[i] / sa
            for j in range(ny):
                zc[i, 1 + j] = s[i, j] * d[j] / sa
        if m == 6:
            for i in range(3):
                zc[3 + i, 0] = (ads_rate[k, i] - w[i]) / er  # z_r = ω_ADS − ω̂
                for j in range(ny):
                    zc[3 + i, 1 + j] = hr[i, j] * d[j] / er
        if slot[k] >= 0:
            sens_s[slot[k]] = s

        updated = meas[k]
        if updated:
            rows += m
            mm(hn, x, nu)  # ν = Z − H̃ X
            for i in range(m):
                for j in range(nc):
                    nu[i, j] = zc[i, j] - nu[i, j]
            mm(hn, p, ut)  # Uᵀ = H̃ P
            mt(ut, hn, smat)  # S = H̃ P H̃ᵀ + R̃
            for i in range(m):
                for j in range(m):
                    smat[i, j] += r_t[i, j]
            symmetrize_inplace(smat)
            if not inverse_spd(smat, sinv):
                return -1
            mm(sinv, ut, kt)  # Kᵀ = S⁻¹ Uᵀ
            mm(sinv, nu, wm)  # S⁻¹ ν
            tm_add(nu, wm, g)  # G += νᵀ S⁻¹ ν
            nu_all[k] = nu
            sinv_all[k] = sinv
            for i in range(nx):
                for j in range(m):
                    gain_all[k, i, j] = kt[j, i]
            tm_add(kt, nu, x)  # X += K ν
            # P ← (I − K H̃) P (I − K H̃)ᵀ + K R̃ Kᵀ
            ikh[:] = 0.0
            tm_add(kt, hn, ikh)
            for i in range(nx):
                for j in range(nx):
                    ikh[i, j] = (1.0 if i == j else 0.0) - ikh[i, j]
            mm(ikh, p, t1)
            mt(t1, ikh, p)
            mm(r_t, kt, rk)
            tm_add(kt, rk, p)
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
        exp_and_left_jacobian(phi, rot, jac)  # R = Exp(−ω̂Δt), Γ = Δt J_l(−ω̂Δt)
        mm(jac, a, ga)
        for i in range(3):
            for j in range(3):
                ga[i, j] *= dt
        fbar[:] = 0.0
        qbar[:] = 0.0
        mt(ga, ga, t1)
        for i in range(3):
            for j in range(3):
                fbar[i, j] = rot[i, j]
                fbar[i, 3 + j] = -ga[i, j] * er / sa
                qbar[i, j] = sv2dt * t1[i, j] / (sa * sa)
            fbar[3 + i, 3 + i] = 1.0
            qbar[3 + i, 3 + i] = su * su * dt / (er * er)
        correlated = updated and m == 6
        if correlated:
            mt(ga, a, ctr)  # C̃_θr = Γ A Aᵀ σ_v²/Δt / (σ_a e_r)
            for i in range(3):
                for j in range(3):
                    ctr[i, j] *= sv2dt / (sa * er)
            mm(ctr, rr_inv, cr)
            mm(cr, a, rot)  # −C̃ R̃⁻¹ H̃_r with H̃_r = [0, −A]  (rot reused as scratch)
            mt(cr, ctr, jac)  # C̃ R̃⁻¹ C̃ᵀ  (jac reused as scratch)
            for i in range(3):
                for j in range(3):
                    fbar[i, 3 + j] += rot[i, j]
                    qbar[i, j] -= jac[i, j]
        mm(fbar, x, tmpx)
        if correlated:
            for i in range(3):
                for j in range(nc):
                    v = 0.0
                    for cc in range(3):
                        v += cr[i, cc] * zc[3 + cc, j]
                    tmpx[i, j] += v
        x[:] = tmpx
        mm(fbar, p, t1)
        mt(t1, fbar, p)
        for i in range(nx):
            for j in range(nx):
                p[i, j] += qbar[i, j]
        symmetrize_inplace(p)
        fbar_all[k] = fbar

        # attitude and sensitivity to k+1 (rot and jac recomputed: reused above)
        step_attitude(q[k], w, hr, dt, s, phi, rot, jac, q[k + 1])
    return rows
