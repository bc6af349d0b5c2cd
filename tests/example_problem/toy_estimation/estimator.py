"""The estimator: a scalar Kalman filter on every trial at once."""

from __future__ import annotations

import numpy as np

from tests.example_problem.toy_estimation.config import ToyConfig


def kalman_filter(cfg: ToyConfig, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Estimates x̂ (B, N) and variances P (N,) after each epoch's update, from readings ``z``
    (B, N), u. The gain does not depend on the data, so P is the same for every trial."""
    w = cfg.walk
    q = w.walk_u_per_sqrt_s**2 * w.dt_s  # u², process noise per step
    r = (w.noise_u if w.assumed_noise_u is None else w.assumed_noise_u) ** 2  # u²
    est = np.empty_like(z)
    var = np.empty(z.shape[1])
    x, p = np.zeros(z.shape[0]), w.prior_sd_u**2  # prior at the first reading's epoch
    for k in range(z.shape[1]):
        if k > 0:
            p += q  # predict: x(k) = x(k − 1) + w, w ~ N(0, q)
        gain = p / (p + r)  # K = P⁻ / (P⁻ + R)
        x = x + gain * (z[:, k] - x)  # x̂ = x̂⁻ + K (z − x̂⁻)
        p = (1.0 - gain) * p  # P = (1 − K) P⁻
        est[:, k], var[k] = x, p
    return est, var
