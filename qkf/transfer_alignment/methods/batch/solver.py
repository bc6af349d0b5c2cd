r"""Gauss–Newton iteration of the batch estimator, one trial per thread (compiled).

Per pass, the normal equations of the whitened residuals (:mod:`.forward`) in units scaled by
the prior sigmas ``d`` (``ỹ = y / d``), with the prior ``P_y0 = diag(d²)`` as a pseudo-observation::

    (G_HH + I) dỹ = G_Hz − ỹ,      cov(ỹ) = (G_HH + I)⁻¹

then ``y ← y + d ∘ dỹ``, re-propagate, until every component of the step is below ``tol`` times
its standard deviation; then the smoothing pass (:mod:`.smoother`) at the last point.
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit, row_loops
from qkf.transfer_alignment.methods.batch.dense import inverse_spd
from qkf.transfer_alignment.methods.batch.forward import forward_pass
from qkf.transfer_alignment.methods.batch.sensitivity import N_Y
from qkf.transfer_alignment.methods.batch.smoother import smooth
from qkf.transfer_alignment.methods.batch.structs import (
    Constants,
    Inputs,
    Nuisance,
    Outputs,
    PassStore,
    TrialData,
)
from qkf.transfer_alignment.model_compiled import rate_estimate

N_C = N_Y + 1
"""Columns of the normal equations: the residual and the 15 Jacobian columns."""


@kernel_jit(nrt=True)
def solve_normal(g: np.ndarray, y_scaled: np.ndarray, step: np.ndarray, cov: np.ndarray) -> bool:
    """Scaled normal equations ``(G_HH + I) dỹ = G_Hz − ỹ`` into ``step``; ``cov`` =
    ``(G_HH + I)⁻¹``. False if the normal matrix is not positive definite."""
    ny = y_scaled.shape[0]
    nmat = np.empty((ny, ny))
    for i in range(ny):
        for j in range(ny):
            nmat[i, j] = 0.5 * (g[1 + i, 1 + j] + g[1 + j, 1 + i])
        nmat[i, i] += 1.0
    if not inverse_spd(nmat, cov):
        return False
    for i in range(ny):
        v = 0.0
        for j in range(ny):
            v += cov[i, j] * (g[1 + j, 0] - y_scaled[j])
        step[i] = v
    return True


@kernel_jit(nrt=True)
def solve_trial(b: int, inputs: Inputs, c: Constants, out: Outputs) -> None:
    """Gauss–Newton passes and the smoothing pass of trial ``b``; writes row ``b`` of ``out``
    (NaN everywhere if a pass fails). ``out.info[b]`` = [passes, converged, χ², rows]."""
    data = TrialData(
        inputs.gyro[b], inputs.ads_q[b], inputs.ads_rate[b], inputs.meas[b], inputs.slot
    )
    est, cov_out, info = out.est[b], out.cov[b], out.info[b]
    y_out, cov_y_out, step_out = out.y[b], out.cov_y[b], out.step[b]
    d = c.d
    n = data.gyro.shape[0]
    m = 6 if c.use_rate else 3
    sr, sv, dt = c.sigma_r, c.sigma_v, c.dt
    er = np.sqrt(sr * sr + sv * sv / dt)  # e_r = √(σ_r² + σ_v²/Δt), scale of the rate rows
    n_slot = cov_out.shape[0]

    # storage of the last forward pass, for the backward pass
    store = PassStore(
        np.empty((n, 4)),  # q
        np.empty((max(n_slot, 1), 3, N_Y)),  # sens_s
        np.empty((n, 6)),  # xz
        np.empty((n, 6, 6)),  # pplus
        np.zeros((n, m, N_C)),  # nu_all
        np.zeros((n, m, m)),  # sinv_all
        np.zeros((n, 6, m)),  # gain_all
        np.empty((n, 6, 6)),  # fbar_all
        np.empty((max(n_slot, 1), 6, N_C)),  # xs
    )
    nuis = Nuisance(np.zeros((m, 6)), np.zeros((m, m)))

    y = np.zeros(N_Y)
    y_scaled = np.zeros(N_Y)
    step = np.zeros(N_Y)
    cov_y = np.zeros((N_Y, N_Y))
    g = np.zeros((N_C, N_C))
    a = np.empty((3, 3))
    w = np.empty(3)
    ok = True
    converged = False
    passes = 0
    rows = 0
    for it in range(c.max_iter):
        passes = it + 1
        if not rate_estimate(data.gyro[0], y[3:6], y[6:15], a, w):  # A = (I + K(p))⁻¹
            ok = False
            break
        rows = forward_pass(data, y, a, c, er, store, g, nuis)
        if rows < 0:
            ok = False
            break
        for i in range(N_Y):
            y_scaled[i] = y[i] / d[i]
        if not solve_normal(g, y_scaled, step, cov_y):
            ok = False
            break
        worst = 0.0
        for i in range(N_Y):
            worst = max(worst, np.abs(step[i]) / np.sqrt(cov_y[i, i]))
        if not np.isfinite(worst):
            ok = False
            break
        if worst < c.tol:
            converged = True
            break
        if it == c.max_iter - 1:
            break
        for i in range(N_Y):
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
    # back to SI: y, its step and covariance
    for i in range(N_Y):
        y_out[i] = y[i]
        step_out[i] = step[i] * d[i]
        for j in range(N_Y):
            cov_y_out[i, j] = cov_y[i, j] * d[i] * d[j]
    smooth(store, data, nuis.hn, y, cov_y_out, d, c.sigma_a, er, est, cov_out)


solve_trials = row_loops(solve_trial, "inputs.gyro.shape[0]").parallel
""":func:`solve_trial` for every trial of ``inputs`` (its arguments after the trial index),
trials in parallel; ``out`` is written in place."""
