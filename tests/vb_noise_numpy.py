"""The numpy reference of the VB noise scales' measurement statistic
(``qkf.redundant_gyros.vb_noise.measurement_statistic`` is compiled): the calibration UKF's
measurement model vectorised, and the statistic written with it (tests/test_gyro_vb_noise.py
holds the model to the filter's own functions and the compiled statistic to this one)."""

from __future__ import annotations

import numpy as np

from qkf.redundant_gyros.ukf import UkfSetup


def measurement_terms(
    setup: UkfSetup, x: np.ndarray, rate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``h(x)`` (...,) deg/s, its Jacobian ``H`` (..., 4) and ``R₀(x)`` (...,) (deg/s)² at
    states ``x`` (..., 4) with triad rates ``rate`` (..., 3)."""
    b, lam, du, dv = (x[..., i] for i in range(4))
    w_bar = setup.w - du[..., None] * setup.u - dv[..., None] * setup.v  # (..., 3)
    w_rate = np.einsum("...m,...m->...", w_bar, rate)
    h = (1.0 - lam) * w_rate - b
    jac = np.stack(
        [
            -np.ones_like(b),
            -w_rate,
            -(1.0 - lam) * (rate @ setup.u),
            -(1.0 - lam) * (rate @ setup.v),
        ],
        axis=-1,
    )
    through = ((1.0 - lam)[..., None] * w_bar @ setup.triad_inv) * setup.triad_noise
    r0 = setup.noise**2 + np.sum(through * through, axis=-1)
    return h, jac, r0


def measurement_statistic(
    setup: UkfSetup,
    est: np.ndarray,
    cov: np.ndarray,
    x_prev: np.ndarray,
    theta_r: np.ndarray,
    z: np.ndarray,
    rate: np.ndarray,
) -> np.ndarray:
    """``s_R`` (n, P): ``((z − h(x̂_k))² + θ̂_R H P_k Hᵀ) / R₀(x̂_{k−1})`` per epoch, NaN where
    the epoch did not run (the arguments of the compiled one)."""
    ran = np.isfinite(est).all(axis=2) & np.isfinite(cov).all(axis=(2, 3))
    x_k = np.where(ran[:, :, None], est, 0.0)
    x_before = np.concatenate([x_prev[:, None, :], x_k[:, :-1, :]], axis=1)  # x̂_{k−1}
    h, jac, _ = measurement_terms(setup, x_k, rate)
    _, _, r0 = measurement_terms(setup, x_before, rate)
    p_k = np.where(ran[:, :, None, None], cov, 0.0)
    hph = np.einsum("...i,...ij,...j->...", jac, p_k, jac)
    return np.asarray(np.where(ran, ((z - h) ** 2 + theta_r[:, None] * hph) / r0, np.nan))
