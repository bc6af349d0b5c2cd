r"""Sage–Husa adaptive Kalman filter on the calibration block (SPEC §3).

With forgetting factor ``b`` and ``d_k = (1 − b)/(1 − b^{k+1})``, the process noise per step of
each calibration term ``i`` is estimated as::

    Q̂_k = (1 − d_k) Q̂_{k−1} + d_k (K ν νᵀ Kᵀ + P_k − Φ P_{k−1} Φᵀ)_ii

where ``Kν`` is the correction of epoch k's update and ``P_k`` the posterior covariance. On the
calibration block Φ is the identity, so ``(Φ P_{k−1} Φᵀ)_ii`` is the previous posterior
variance. Safeguards: only the diagonal is adapted, and ``Q̂`` is clipped to
``[κ_min, κ_max] · q_p0 Δt`` (the ends of the action set), which keeps it positive definite
and finite. The filter's update and propagation of an epoch run in one compiled call, so the
``Q̂`` estimated at epoch k drives the propagation that starts at epoch k + 1 (a lag of one
step against a smoothing window of ~1/(1 − b) steps).
"""

from __future__ import annotations

import numpy as np

from qkf.config import Config
from qkf.methods.base import MethodOutput, action_values, new_filter
from qkf.scenario import ScenarioData


def forgetting_weights(b: float, n: int) -> np.ndarray:
    """``d_k = (1 − b)/(1 − b^{k+1})`` for k = 0 … n − 1."""
    k = np.arange(n)
    return (1.0 - b) / (1.0 - b ** (k + 1))


def sage_husa_step(
    q_prev: np.ndarray,
    d_k: float,
    correction: np.ndarray,
    var_post: np.ndarray,
    var_prev_post: np.ndarray,
    q_min: float,
    q_max: float,
) -> np.ndarray:
    """One Sage–Husa update of the per-step process noise of each term, clipped; any shape."""
    observed = correction**2 + var_post - var_prev_post
    return np.clip((1.0 - d_k) * q_prev + d_k * observed, q_min, q_max)


def run_sage_husa(cfg: Config, data: ScenarioData) -> MethodOutput:
    """Sage–Husa AKF, batched over trials; logs ``Q̂`` per epoch as κ = Q̂ / (q_p0 Δt)."""
    kf = new_filter(cfg, data)
    b, n = data.n_trials, data.n_epochs
    dt, qp0 = cfg.scenario.dt_s, cfg.filter.qp0
    kappas = action_values(cfg)
    q_min, q_max = kappas.min() * qp0 * dt, kappas.max() * qp0 * dt
    d = forgetting_weights(cfg.adaptive.sage_husa.forgetting, n)
    q_hat = np.full((b, 9), qp0 * dt)
    var_prev = np.broadcast_to(kf.P[:, np.arange(6, 15), np.arange(6, 15)], (b, 9)).copy()
    est = np.empty((b, n, 16))
    kappa_log = np.empty((b, n, 9))
    for k in range(n):
        kappa = q_hat / (qp0 * dt)
        kappa_log[:, k] = kappa
        rec = kf.step_data(data, k, k + 1, kappa=kappa[:, None, :])
        est[:, k] = rec.est[:, 0]
        var_post = rec.var[:, 0, 6:15]
        q_hat = sage_husa_step(q_hat, d[k], rec.dx[:, 0, 6:15], var_post, var_prev, q_min, q_max)
        # a diverged trial's NaNs stay in its own rows; keep the clip range for the others
        q_hat = np.where(np.isfinite(q_hat), q_hat, qp0 * dt)
        var_prev = var_post
    return MethodOutput(est=est, diverged=kf.diverged.copy(), extras={"kappa": kappa_log})
