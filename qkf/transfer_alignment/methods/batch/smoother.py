r"""Smoothing pass of the batch estimator: the reported estimates and covariances (compiled).

Modified Bryson–Frazier smoothing of the nuisance over the whole run. With the adjoint ``λ⁺_k``
(6×16) and ``Λ⁺_k`` (6×6) after the update of epoch k::

    x_{k|N} = x⁺_k + P⁺_k λ⁺_k,          P_{k|N} = P⁺_k − P⁺_k Λ⁺_k P⁺_k
    λ⁻ = H̃ᵀ S⁻¹ ν + (I − K H̃)ᵀ λ⁺,       Λ⁻ = H̃ᵀ S⁻¹ H̃ + (I − K H̃)ᵀ Λ⁺ (I − K H̃)
    λ⁺_{k−1} = F̄ᵀ λ⁻,                    Λ⁺_{k−1} = F̄ᵀ Λ⁻ F̄

Reported per epoch: ``Ĉ_k Exp(ξ̂_k)``, ``b̂ + β̂_k`` and ``p̂``; at the sampled epochs the
covariance ``M_k P_y M_kᵀ + P^n_{k|N}`` (``M_k`` maps ``dy`` to the error state).
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit
from qkf.core.kalman import symmetrize_inplace
from qkf.core.quat import quat_mul_exp
from qkf.transfer_alignment.methods.batch.dense import mm, mm_add, mt, tm_add
from qkf.transfer_alignment.methods.batch.structs import PassStore, TrialData


@kernel_jit(nrt=True)
def smooth(
    store: PassStore,
    data: TrialData,
    hn: np.ndarray,
    y: np.ndarray,
    cov_y: np.ndarray,
    d: np.ndarray,
    sa: float,
    er: float,
    est: np.ndarray,
    cov_out: np.ndarray,
) -> None:
    """Backward pass over the forward pass in ``store`` at the solution ``y`` (SI) with
    covariance ``cov_y``: writes ``est`` (N, 16) and ``cov_out`` (M, 15, 15), SI.

    ``hn`` = H̃ of the nuisance filter, ``d`` the scale of ``y``, ``sa`` = σ_a and ``er`` = e_r
    the scales of the nuisance states ξ and β.
    """
    q, sens_s, xz, pplus, xs = store.q, store.sens_s, store.xz, store.pplus, store.xs
    nu_all, sinv_all, gain_all, fbar_all = (
        store.nu_all,
        store.sinv_all,
        store.gain_all,
        store.fbar_all,
    )
    meas, slot = data.meas, data.slot
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
    for k in range(n - 1, -1, -1):
        pk[:] = pplus[k]
        # smoothed nuisance of the residual column: the reported estimate
        for i in range(nx):
            v = xz[k, i]
            for c in range(nx):
                v += pk[i, c] * lam[c, 0]
            if i < 3:
                phi[i] = sa * v  # ξ̂_k
            else:
                est[k, 1 + i] = y[i] + er * v  # b̂ + β̂_k (y[3:6] = b̂)
        quat_mul_exp(q[k], phi, est[k, 0:4])  # Ĉ_k Exp(ξ̂_k)
        for i in range(9):
            est[k, 7 + i] = y[6 + i]
        j_slot = slot[k]
        if j_slot >= 0:
            xsm[:] = xs[j_slot]
            mm_add(pk, lam, xsm)
            mm(big, pk, t1)  # P_{k|N} = P⁺ − P⁺ Λ P⁺
            mm(pk, t1, psm)
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
            mm(mmat, cov_y, mp)
            out = cov_out[j_slot]
            mt(mp, mmat, out)
            for i in range(nx):
                si = sa if i < 3 else er
                for j in range(nx):
                    out[i, j] += si * (sa if j < 3 else er) * psm[i, j]
            symmetrize_inplace(out)
        if k == 0:
            break
        if meas[k]:  # measurement step backwards
            mm(sinv_all[k], hn, hts)
            ikh[:] = 0.0
            mm_add(gain_all[k], hn, ikh)
            for i in range(nx):
                for j in range(nx):
                    ikh[i, j] = (1.0 if i == j else 0.0) - ikh[i, j]
            lam_m[:] = 0.0
            tm_add(hts, nu_all[k], lam_m)  # H̃ᵀ S⁻¹ ν
            tm_add(ikh, lam, lam_m)  # + (I − K H̃)ᵀ λ
            mm(big, ikh, t1)
            big_m[:] = 0.0
            tm_add(ikh, t1, big_m)  # (I − K H̃)ᵀ Λ (I − K H̃)
            tm_add(hn, hts, big_m)  # + H̃ᵀ S⁻¹ H̃
        else:
            lam_m[:] = lam
            big_m[:] = big
        fk[:] = fbar_all[k - 1]  # time step backwards
        lam[:] = 0.0
        tm_add(fk, lam_m, lam)
        mm(big_m, fk, t1)
        big[:] = 0.0
        tm_add(fk, t1, big)
        symmetrize_inplace(big)
