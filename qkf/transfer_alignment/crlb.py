r"""Posterior Cramér–Rao lower bound of the transfer-alignment problem (docs/models.md).

The system linearised along the *true* trajectory (``F``, ``H`` at the true ``ω`` and ``p``;
true noise levels; the scenario's true ``q_p``, floored at 1e-20 /s) is linear and Gaussian, so
its posterior Fisher information obeys the recursion::

    J_0 = P_0⁻¹,   J_k ← J_k + H_kᵀ R_k⁻¹ H_k,   J_{k+1} = (Q_k + Φ_k J_k⁻¹ Φ_kᵀ)⁻¹

and ``J_k⁻¹`` is the covariance of the optimal (Kalman) filter for that system. It is computed
here in that covariance form, in units scaled by the prior sigmas, because the information
matrices span 16 orders of magnitude. With rate matching the rate-measurement noise and the
attitude process noise share the gyro noise (cross-covariance ``C = Γ A σ_v²/Δt Aᵀ``); the
recursion then carries the correlated-noise terms (see ``qkf.transfer_alignment.filter``),
otherwise the bound would be optimistic. ``bound_k = sqrt(diag J_k⁻¹)`` after the measurement
of epoch ``k``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.model import discretize, measurement_model, rate_matrix
from qkf.transfer_alignment.params import TruthParams, prior_sigma
from qkf.transfer_alignment.scenario import (
    calibration_jumps,
    calibration_walk_sigma,
    measurement_mask,
    true_rates,
)

QP_FLOOR = 1e-20
"""Calibration process-noise density used when the truth has none, 1/s."""


@dataclass(frozen=True)
class CrlbResult:
    t: np.ndarray  # (N,) s
    bound: np.ndarray  # (N, 15) 1-σ bounds, SI
    cov: np.ndarray  # (N, 15, 15) J⁻¹, SI


def true_calibration_path(cfg: Config) -> np.ndarray:
    """The deterministic part of the true calibration vector per epoch (N, 9): truth + jumps."""
    tp = TruthParams.from_config(cfg)
    return tp.p0[None, :] + calibration_jumps(cfg.scenario)


def crlb(cfg: Config, use_rate: bool | None = None) -> CrlbResult:
    """The bound for the scenario of ``cfg``; ``use_rate`` defaults to the filter's matching."""
    tp = TruthParams.from_config(cfg)
    if use_rate is None:
        use_rate = cfg.filter.matching == "attitude_rate"
    dt, n = tp.dt, tp.n_epochs
    w = true_rates(cfg.scenario)
    a = rate_matrix(true_calibration_path(cfg))  # A = (I + K(p))⁻¹ along the true path
    q_p = np.maximum(calibration_walk_sigma(cfg.scenario) ** 2, QP_FLOOR)
    phi, qd = discretize(w, a, dt, tp.sigma_v, tp.sigma_u, q_p, cfg.filter.quadrature_nodes)
    h, r = measurement_model(w, a, dt, tp.sigma_a, tp.sigma_r, tp.sigma_v, use_rate)
    has_meas = measurement_mask(cfg.scenario)
    m = h.shape[1]
    c = np.zeros((n, 15, m))
    if use_rate:
        gamma = -phi[:, 0:3, 3:6] @ np.linalg.inv(a)
        c[:, 0:3, 3:6] = gamma @ a @ np.swapaxes(a, -1, -2) * (tp.sigma_v**2 / dt)

    # scaled units: x̃ = x / d, z̃ = z / e
    d = prior_sigma(cfg)
    dd = d[:, None] * d[None, :]
    e = np.sqrt(np.diagonal(r, axis1=1, axis2=2))  # (N, m)
    p = np.eye(15)
    bound = np.empty((n, 15))
    cov = np.empty((n, 15, 15))
    eye = np.eye(15)
    for k in range(n):
        phi_k = phi[k] * d[None, :] / d[:, None]
        q_k = qd[k] / dd
        gain = None
        if has_meas[k]:
            h_k = h[k] * d[None, :] / e[k][:, None]
            r_k = r[k] / (e[k][:, None] * e[k][None, :])
            s_k = h_k @ p @ h_k.T + r_k
            s_inv = np.linalg.inv(s_k)
            gain = p @ h_k.T @ s_inv
            ikh = eye - gain @ h_k
            p = ikh @ p @ ikh.T + gain @ r_k @ gain.T
            p = 0.5 * (p + p.T)
        cov[k] = p * dd
        bound[k] = np.sqrt(np.diag(p)) * d
        p = phi_k @ p @ phi_k.T + q_k
        if gain is not None and use_rate:
            c_k = c[k] / (d[:, None] * e[k][None, :])
            corr = phi_k @ gain @ c_k.T
            p = p - corr - corr.T - c_k @ s_inv @ c_k.T
        p = 0.5 * (p + p.T)
    return CrlbResult(t=np.arange(n) * dt, bound=bound, cov=cov)
