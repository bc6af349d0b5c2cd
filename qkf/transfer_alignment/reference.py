"""A plain, slow reference implementation of the transfer-alignment filter on filterpy.

One ``filterpy.kalman.KalmanFilter`` per trial, stepped epoch by epoch with ``Φ``, ``Q_d``,
``H`` and ``R`` from :mod:`qkf.transfer_alignment.model` and quaternion algebra from scipy. It
shares no code with the compiled kernel beyond the model equations, so it serves to check the kernel
(tests) and as the speed reference (``benchmarks/filter_speed.py``).
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter
from scipy.spatial.transform import Rotation

from qkf.transfer_alignment.filter import FilterParams
from qkf.transfer_alignment.model import discretize, measurement_model, rate_estimate


def run_reference(
    params: FilterParams,
    gyro: np.ndarray,
    ads_q: np.ndarray,
    ads_rate: np.ndarray,
    has_meas: np.ndarray,
    kappa: float | np.ndarray = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Filter one trial: inputs (n, 3), (n, 4), (n, 3), (n,); ``kappa`` a scalar or (n, 9).
    Returns the a-posteriori estimates (n, 16) = [q̂, b̂, p̂] and covariances (n, 15, 15), SI."""
    n = gyro.shape[0]
    m = params.n_meas
    kf = KalmanFilter(dim_x=15, dim_z=m)
    kf.x = np.zeros(15)
    kf.P = np.diag(params.p0_sigma**2)
    c_hat = Rotation.from_quat(ads_q[0])
    b_hat = np.zeros(3)
    p_hat = np.zeros(9)
    q_diag = np.broadcast_to(np.asarray(kappa, dtype=float), (n, 9)) * params.qp0
    est = np.empty((n, 16))
    cov = np.empty((n, 15, 15))
    correlated = params.use_rate and params.rate_noise_correlation
    for k in range(n):
        a, w = rate_estimate(gyro[k], b_hat, p_hat)
        updated = False
        if has_meas[k]:
            updated = True
            z_a = (c_hat.inv() * Rotation.from_quat(ads_q[k])).as_rotvec()
            z = np.concatenate([z_a, ads_rate[k] - w]) if params.use_rate else z_a
            h, r = measurement_model(
                w, a, params.dt, params.sigma_a, params.sigma_r, params.sigma_v, params.use_rate
            )
            kf.x = np.zeros(15)
            kf.update(z, R=r, H=h)
            dx = np.asarray(kf.x).ravel()
            c_hat = c_hat * Rotation.from_rotvec(dx[0:3])
            b_hat = b_hat + dx[3:6]
            p_hat = p_hat + dx[6:15]
            kf.x = np.zeros(15)
            a, w = rate_estimate(gyro[k], b_hat, p_hat)
        est[k, 0:4] = c_hat.as_quat()
        est[k, 4:7] = b_hat
        est[k, 7:16] = p_hat
        cov[k] = kf.P
        phi, qd = discretize(
            w,
            a,
            params.dt,
            params.sigma_v,
            params.sigma_u,
            0.0,
            params.quadrature_nodes,
            q_p_diag=q_diag[k],
        )
        kf.predict(F=phi, Q=qd)
        c_hat = c_hat * Rotation.from_rotvec(w * params.dt)
        if updated and correlated:
            # cross-covariance of attitude process noise and rate-measurement noise
            c = np.zeros((15, 6))
            gamma = -phi[0:3, 3:6] @ np.linalg.inv(a)
            c[0:3, 3:6] = gamma @ a @ a.T * params.sigma_v**2 / params.dt
            si = np.linalg.inv(kf.S)
            corr = phi @ kf.K @ c.T
            kf.P = kf.P - corr - corr.T - c @ si @ c.T
            c_hat = c_hat * Rotation.from_rotvec((c @ si @ kf.y)[0:3])
    return est, cov
