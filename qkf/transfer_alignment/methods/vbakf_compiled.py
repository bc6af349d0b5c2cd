r"""The VBAKF measurement update compiled (numba), tested against the numpy reference
``vb_step`` of ``tests/vbakf_numpy.py``, and the per-epoch step of
:func:`~qkf.transfer_alignment.methods.vbakf.run_vbakf` built on it.

The equations are those of Huang et al. 2018, Algorithm 1 (module docstring of
:mod:`qkf.transfer_alignment.methods.vbakf`), written in the correction ``δx̂⁽ⁱ⁾ = x̂⁽ⁱ⁾ − x̂⁻``
and the innovation ``ν = z − H x̂⁻`` (in :func:`run_vbakf` the error state is reset, ``x̂⁻ = 0``,
so these are the iterate and ``z`` themselves)::

    û⁻ = ρ (û_{k−1} − a − 1) + a + 1,   Û⁻ = ρ Û_{k−1},   T̂⁻ = τ P̃⁻
    δx̂⁽⁰⁾ = 0,  P⁽⁰⁾ = P̃⁻
    for i = 0 … N − 1:
        P̂⁻ = sym(τ P̃⁻ + δx̂ δx̂ᵀ + P⁽ⁱ⁾) / (τ + 1)                  A = δx̂ δx̂ᵀ + P⁽ⁱ⁾
        ε  = (ν − H δx̂)_a,  û = û⁻ + 1,  Û = Û⁻ + ε εᵀ + sym(H_a P⁽ⁱ⁾ H_aᵀ)      (B)
        R̂  = R̃ with the a × a block Û / (û − a − 1)  (isotropic: tr(·)/a · I)
        U  = H P̂⁻,  S = sym(U Hᵀ + R̂) = L Lᵀ,  Kᵀ = S⁻¹ U               (Cholesky)
        δx̂⁽ⁱ⁺¹⁾ = K ν
        P⁽ⁱ⁺¹⁾ = sym(P̂⁻ − K U + (K (U Hᵀ + R̂) − Uᵀ) Kᵀ)                 (Joseph form)

The last line is the Joseph form ``(I − K H) P̂⁻ (I − K H)ᵀ + K R̂ Kᵀ`` multiplied out (as
:func:`qkf.core.kalman.update_one` evaluates it): the same matrix for any gain, so it keeps the
Joseph form's robustness to an error in ``K``, at the cost of ``U = H P̂⁻`` (whose zeros are
skipped: the attitude rows of ``H`` have one non-zero) and two m × n × n products instead of
the two n³ ones of ``(I − K H) P̂⁻ (I − K H)ᵀ``. In :func:`run_vbakf` the last iteration stops
after ``P̂⁻`` and ``R̂``: its gain and posterior are the filter's own update, formed there.
The results equal ``vb_step``'s to rounding (the sums run in another order, ``S`` is
factored by Cholesky instead of LU); ``tests/test_methods_vb_cm.py`` checks it. The compiled
step is for the 15 error states of the transfer-alignment model (any ``m`` and adapted
block ``a``); ``vb_step`` is the reference for any size.

:func:`vb_epoch` is one measurement epoch of :func:`run_vbakf` for every trial: the filter's
measurement model at its current estimate, in its scaled units (as
``scaled_measurement`` of ``tests/vbakf_numpy.py``, with the compiled ``A`` of
:mod:`qkf.transfer_alignment.model_compiled`, the filter's own), the finiteness checks, the N
iterations, and the hand-over (``P̂⁻``, ``σ̂_a``, the R posterior, the effective κ). Trials run
in parallel (``prange``; :func:`vb_epoch_serial` runs the same per-trial code in the calling
thread, for small batches) and each reads and writes only its own rows, so a non-finite trial
never touches another.

Units: the VB arithmetic runs in the filter's scaled units (dimensionless: ``P̃ = D⁻¹ P D⁻¹``,
rows divided by their nominal sigmas ``e``); the model inputs are SI (rad, rad/s, s).
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit, row_loops
from qkf.core.kalman import sparse_rows_times, update_sized
from qkf.transfer_alignment.model import N_STATES
from qkf.transfer_alignment.model_compiled import attitude_residual, rate_estimate, rate_jacobian


@kernel_jit()
def vb_iterate(
    p_nom: np.ndarray,
    nu: np.ndarray,
    h: np.ndarray,
    r_nom: np.ndarray,
    u_prev: float,
    us_prev: np.ndarray,
    tau: float,
    rho: float,
    iterations: int,
    adapt_p: bool,
    adapt_r: bool,
    isotropic: bool,
    posterior: bool,
    dx: np.ndarray,
    p: np.ndarray,
    p_hat: np.ndarray,
    r: np.ndarray,
    us: np.ndarray,
    ws: np.ndarray,
) -> tuple[bool, float]:
    r"""One VBAKF measurement update of one problem (module docstring), into preallocated arrays.

    Inputs: ``p_nom`` (n, n), n = 15, the nominal prediction ``P̃⁻``; ``nu`` (m,) the innovation
    ``ν = z − H x̂⁻``; ``h`` (m, n); ``r_nom`` (m, m) R as assumed, whose leading a × a block is
    adapted (``a`` = size of ``us_prev``); ``u_prev``, ``us_prev`` (a, a) the R posterior of the
    previous measurement (``û``, ``Û``); ``τ``, ``ρ``, N = ``iterations`` ≥ 1; ``isotropic``:
    update with ``(tr R̂_a / a) I``.

    Outputs: ``dx`` (n,) ``x̂⁽ᴺ⁾ − x̂⁻``; ``p`` (n, n) ``P⁽ᴺ⁾``; ``p_hat`` (n, n) ``P̂⁻`` and
    ``r`` (m, m) ``R̂`` of the last iteration; ``us`` (a, a) ``Û``. With ``posterior`` False
    the last iteration stops after ``P̂⁻`` and ``R̂`` (its gain, ``dx`` and ``p`` are not
    formed; ``dx``, ``p`` then hold the iterate N − 1). ``ws`` (≥ 7, ≥ max(m, a + 1),
    ≥ max(m, n)) is scratch.

    Returns ``(ok, û)``; ``ok`` is False if a Cholesky pivot of ``S`` is not positive (or NaN);
    the outputs are then partial.

    ``n`` is the model's 15 error states (:data:`~qkf.transfer_alignment.model.N_STATES`), a
    compile-time constant: the row loops then have a known trip count and vectorise without
    runtime checks (about 25 % faster than with ``n`` read from the shapes). The callers
    (:func:`vb_epoch`; ``vb_step(..., compiled=True)`` of ``tests/vbakf_numpy.py``) check the
    shapes.
    """
    n = N_STATES  # compile-time trip count of the row loops
    m = nu.shape[0]
    a = us_prev.shape[0]
    ut = ws[0]  # U = H P̂⁻ (m × n)
    kt = ws[1]  # Kᵀ (m × n)
    g = ws[2]  # (K (H P̂⁻ Hᵀ + R̂) − Uᵀ)ᵀ (m × n)
    hpa = ws[3]  # H_a P (a × n), rows 0..a−1
    s = ws[4]  # S, then its Cholesky factor (m × m block)
    hph = ws[5]  # H P̂⁻ Hᵀ (m × m block)
    eps = ws[3, a]  # ε = (z − H x̂⁽ⁱ⁾)_a = (ν − H δx̂)_a (a,), below the rows of H_a P
    inv_tau1 = 1.0 / (tau + 1.0)
    u_pred = rho * (u_prev - a - 1.0) + a + 1.0  # û⁻ = ρ (û − a − 1) + a + 1
    u = u_pred
    for i in range(a):
        for j in range(a):
            us[i, j] = rho * us_prev[i, j]  # Û = Û⁻ = ρ Û_{k−1} until adapted
    for i in range(n):
        dx[i] = 0.0  # δx̂⁽⁰⁾ = 0
        for j in range(n):
            p[i, j] = p_nom[i, j]  # P⁽⁰⁾ = P̃⁻
            p_hat[i, j] = p_nom[i, j]  # P̂⁻ = P̃⁻ unless adapted
    for i in range(m):
        for j in range(m):
            r[i, j] = r_nom[i, j]  # R̂ = R̃ unless adapted
    for it in range(iterations):
        last = it == iterations - 1
        if adapt_p:
            # P̂⁻ = T̂ / (t̂ − n − 1) = sym(τ P̃⁻ + A) / (τ + 1),  A = δx̂ δx̂ᵀ + P⁽ⁱ⁾
            for i in range(n):
                for j in range(i, n):
                    mij = tau * p_nom[i, j] + (dx[i] * dx[j] + p[i, j])
                    mji = tau * p_nom[j, i] + (dx[j] * dx[i] + p[j, i])
                    v = 0.5 * (mij + mji) * inv_tau1
                    p_hat[i, j] = v
                    p_hat[j, i] = v
        if adapt_r:
            # ε = (z − H x̂⁽ⁱ⁾)_a = (ν − H δx̂)_a
            for i in range(a):
                v = nu[i]
                for c in range(n):
                    v -= h[i, c] * dx[c]
                eps[i] = v
            sparse_rows_times(h, p, hpa, a, n)  # H_a P⁽ⁱ⁾ (a × n), zeros of H skipped
            u = u_pred + 1.0  # û = û⁻ + 1
            den = u - a - 1.0  # û − a − 1
            for i in range(a):
                for j in range(i, a):
                    vij = 0.0
                    vji = 0.0
                    for c in range(n):
                        vij += hpa[i, c] * h[j, c]
                        vji += hpa[j, c] * h[i, c]
                    # Û = Û⁻ + B,  B = ε εᵀ + sym(H_a P Hᵀ_a)
                    v = rho * us_prev[i, j] + (eps[i] * eps[j] + 0.5 * (vij + vji))
                    us[i, j] = v
                    us[j, i] = v
            if isotropic:
                tr = 0.0
                for i in range(a):
                    tr += us[i, i] / den  # tr R̂_a,  R̂_a = Û / (û − a − 1)
                tr /= a
                for i in range(a):
                    for j in range(a):
                        r[i, j] = tr if i == j else 0.0
            else:
                for i in range(a):
                    for j in range(a):
                        r[i, j] = us[i, j] / den  # R̂_a = Û / (û − a − 1)
        if last and not posterior:
            break
        # the Joseph-form update from P̂⁻ with R̂ (qkf.core.kalman.update_sized, inlined with
        # n = 15 a constant):  S = H P̂⁻ Hᵀ + R̂,  K = P̂⁻ Hᵀ S⁻¹,  δx̂⁽ⁱ⁺¹⁾ = K ν,
        #   P = (I − K H) P̂⁻ (I − K H)ᵀ + K R̂ Kᵀ  (multiplied out), symmetrised
        for i in range(n):
            dx[i] = 0.0
            for j in range(n):
                p[i, j] = p_hat[i, j]
        ok, _, _ = update_sized(
            dx, p, nu, h, r, s[:m, :m], (ut, kt, g, hph[:m, :m], s[:m, :m], ws[6, 0, :m]), n, m,
            False,
        )  # fmt: skip
        if not ok:  # S not positive definite (or a NaN)
            return False, u
    return True, u


@kernel_jit()
def _all_finite(x: np.ndarray) -> bool:
    for v in x.flat:
        if not np.isfinite(v):
            return False
    return True


@kernel_jit()
def _epoch_trial(
    b: int,
    k: int,
    p_nom: np.ndarray,
    q_hat: np.ndarray,
    b_hat: np.ndarray,
    p_cal: np.ndarray,
    inactive: np.ndarray,
    gyro: np.ndarray,
    ads_q: np.ndarray,
    ads_rate: np.ndarray,
    d: np.ndarray,
    e: np.ndarray,
    model: np.ndarray,
    settings: np.ndarray,
    flags: np.ndarray,
    q_step: np.ndarray,
    u: np.ndarray,
    us: np.ndarray,
    sigma_a: np.ndarray,
    p_out: np.ndarray,
    kappa_out: np.ndarray,
    bad: np.ndarray,
    work: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    r"""Trial ``b`` of one measurement epoch ``k`` of
    :func:`~qkf.transfer_alignment.methods.vbakf.run_vbakf` (for every trial: :data:`vb_epoch`).

    If the trial is not ``inactive`` (diverged, or no measurement at ``k``):

    1. the filter's measurement model at its estimate (``q_hat`` (B, 4) scalar-last, ``b_hat``
       (B, 3) rad/s, ``p_cal`` (B, 9)) in scaled units, ``e`` (m,) the row scales and ``d``
       (15,) the state scales::

           A = (I + K(p̂))⁻¹,  ω̂ = A (ω̃_k − b̂)
           ν̃ = E⁻¹ [Log(Ĉᵀ C_ADS); ω_ADS − ω̂]
           H̃ = E⁻¹ [[I, 0, 0]; [0, −A, −A Ω(ω̂)]] D
           R̃ = E⁻¹ blkdiag(σ_a² I, σ_r² I + σ_v² A Aᵀ / Δt) E⁻¹

       (the rate rows only with ``m = 6``; ``b̂ = p̂ = 0`` where they are not finite);
    2. if ``P̃⁻`` (``p_nom`` (B, 15, 15), scaled), ``ν̃``, ``H̃``, ``R̃`` are finite: the N
       iterations (:func:`vb_iterate`, isotropic ``R̂_a``, no posterior), then
       ``p_out = P̂⁻``, ``σ̂_a² = e_a² tr(R̂_a)/3`` into ``sigma_a`` (rad) and ``û``, ``Û``
       into ``u``, ``us`` (when ``R̂`` is adapted and ``σ̂_a²`` finite and positive);
    3. otherwise, or if the step failed (non-positive pivot of ``S``, non-finite ``P̂⁻``),
       ``p_out = P̃⁻`` and ``bad`` (the trial is to be flagged diverged).

    For every trial ``kappa_out`` (B, 9) = ``clip(1 + (P̂⁻ − P̃⁻)_ii / q_step_i, κ_min,
    κ_max)`` on the calibration terms (1 where not finite). ``model`` = (Δt s, σ_a rad, σ_r
    rad/s, σ_v rad/√s); ``settings`` = (τ, ρ, κ_min, κ_max, N); ``flags`` = (adapt_p, adapt_r);
    ``gyro``, ``ads_q``, ``ads_rate`` the whole (B, N_epochs, ·) records. ``work``: the
    batch's scratch (:func:`_epoch_workspace`).
    """
    hw, rw, vw, pw, ws = work
    n = N_STATES
    m = e.shape[0]
    dt, sig_a, sig_r, sig_v = model[0], model[1], model[2], model[3]
    tau, rho, k_min, k_max = settings[0], settings[1], settings[2], settings[3]
    iterations = int(settings[4])
    adapt_p, adapt_r = flags[0], flags[1]
    pn = p_nom[b]
    h = hw[b]
    r = rw[b]
    nu = vw[b, 0]
    dx = vw[b, 1]
    misc = vw[b, 2]
    a_mat = ws[b, 0, :3, :3]  # A = (I + K(p̂))⁻¹
    w_hat = misc[0:3]  # ω̂ (rad/s)
    b_use = misc[3:6]
    p_use = misc[6:15]
    us_new = ws[b, 1, :3, :3]
    po = p_out[b]
    ok = False
    if not inactive[b]:  # inactive rows (diverged, no measurement) compute nothing
        # estimates that are not finite: the model at b̂ = p̂ = 0 (as scaled_measurement)
        live = _all_finite(b_hat[b]) and _all_finite(p_cal[b])
        for i in range(3):
            b_use[i] = b_hat[b, i] if live else 0.0
        for i in range(9):
            p_use[i] = p_cal[b, i] if live else 0.0
        # A = (I + K(p̂))⁻¹, ω̂ = A (ω̃ − b̂); False if I + K(p̂) is singular or not finite
        ok = rate_estimate(gyro[b, k], b_use, p_use, a_mat, w_hat)
    if ok:
        # ν̃ = E⁻¹ ν,  H̃ = E⁻¹ H D,  R̃ = E⁻¹ R E⁻¹  (model.measurement_model, scaled)
        attitude_residual(q_hat[b], ads_q[b, k], nu)  # z_a = Log(Ĉᵀ C_ADS) (rad)
        for i in range(m):
            for j in range(n):
                h[i, j] = 0.0
            for j in range(m):
                r[i, j] = 0.0
        for i in range(3):
            nu[i] = nu[i] / e[i]
            h[i, i] = d[i] / e[i]  # H_a = [I, 0, 0]
            r[i, i] = sig_a * sig_a / (e[i] * e[i])  # R_a = σ_a² I
        if m == 6:
            rate_jacobian(a_mat, w_hat, h[3:6])  # H_r = [0, −A, −A Ω(ω̂)]
            for i in range(3):
                nu[3 + i] = (ads_rate[b, k, i] - w_hat[i]) / e[3 + i]  # z_r = ω_ADS − ω̂
                for j in range(3, n):
                    h[3 + i, j] = h[3 + i, j] * d[j] / e[3 + i]
                for j in range(3):
                    aat = 0.0
                    for c in range(3):
                        aat += a_mat[i, c] * a_mat[j, c]
                    # R_r = σ_r² I + σ_v² A Aᵀ / Δt
                    rij = sig_v * sig_v / dt * aat + (sig_r * sig_r if i == j else 0.0)
                    r[3 + i, 3 + j] = rij / (e[3 + i] * e[3 + j])
        # no stand-ins needed: a trial whose inputs are not finite is not iterated (and is bad)
        ok = _all_finite(pn) and _all_finite(nu[:m]) and _all_finite(h) and _all_finite(r)
    done = False
    if ok:
        done, u_new = vb_iterate(
            pn, nu[:m], h, r, u[b], us[b], tau, rho, iterations, adapt_p, adapt_r, True, False,
            dx, pw[b, 0], po, pw[b, 1, :m, :m], us_new, ws[b, 2:],
        )  # fmt: skip
        done = done and _all_finite(po)
        if done and adapt_r:
            r_att = pw[b, 1, 0, 0] * e[0] * e[0]  # σ̂_a² = tr(R̂_a)/3 (isotropic, SI)
            if np.isfinite(r_att) and r_att > 0.0:
                sigma_a[b] = np.sqrt(r_att)
                u[b] = u_new
                for i in range(3):
                    for j in range(3):
                        us[b, i, j] = us_new[i, j]
    if not done:
        for i in range(n):
            for j in range(n):
                po[i, j] = pn[i, j]  # P̂⁻ = P̃⁻ where nothing was inferred
    bad[b] = not done and not inactive[b]
    # effective κ of the calibration block: κ_i = clip(1 + (P̂⁻ − P̃⁻)_ii / (q_p0 Δt))
    for i in range(9):
        c = 6 + i
        kap = 1.0 + (po[c, c] - pn[c, c]) / q_step[i]
        kappa_out[b, i] = min(max(kap, k_min), k_max) if np.isfinite(kap) else 1.0


@kernel_jit(nrt=True)
def _epoch_workspace(
    p_nom: np.ndarray, d: np.ndarray, e: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The scratch of :func:`vb_epoch` and :func:`vb_epoch_serial`, per trial: ``H̃`` (B, m, 15),
    ``R̃`` (B, m, m), vectors (B, 3, 15), two n × n matrices (B, 2, 15, 15) and the iteration's
    workspace (B, 9, max(m, 4), 15); after checking the shapes."""
    bsz = p_nom.shape[0]
    m = e.shape[0]
    n = N_STATES
    if p_nom.shape[1:] != (n, n) or d.shape[0] != n or m not in (3, 6):
        raise ValueError("vb_epoch: P̃⁻ must be (B, 15, 15), d (15,), e (3,) or (6,)")
    return (
        np.empty((bsz, m, n)),
        np.empty((bsz, m, m)),
        np.empty((bsz, 3, n)),
        np.empty((bsz, 2, n, n)),
        np.empty((bsz, 9, max(m, 4), n)),
    )


vb_epoch_loops = row_loops(_epoch_trial, "p_nom.shape[0]", scratch=_epoch_workspace)
vb_epoch, vb_epoch_serial = vb_epoch_loops.parallel, vb_epoch_loops.serial
"""The epoch with the trials in parallel, and with the trials one after the other in the calling
thread, for batches below :data:`~qkf.core.jit.SERIAL_BELOW` (``vb_epoch_loops.for_rows``).
One definition, but each compiled copy of the per-trial code rounds on its own: the two differ
in the last bits (about 1e-14 in the estimates of a two-minute run), not more."""
