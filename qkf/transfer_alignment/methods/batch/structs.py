"""Named groups of the batch estimator's arrays and constants (instead of positional packs).

Numba compiles these named tuples into plain structs: reading a field costs nothing, and the
functions of the package take a handful of them instead of two dozen arrays.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Constants(NamedTuple):
    """The filter's assumptions (SI) and the solver's settings, shared by all trials."""

    dt: float  # Δt, s
    sigma_a: float  # ADS attitude sigma σ_a, rad: scale of the attitude rows and of ξ
    sigma_r: float  # ADS rate sigma σ_r, rad/s
    sigma_v: float  # gyro ARW σ_v, rad/√s
    sigma_u: float  # gyro RRW σ_u, rad/s^1.5
    d: np.ndarray  # (15,) prior sigmas of y = [α, b, p] (SI): its scale
    use_rate: bool  # attitude-and-rate matching (6 rows) instead of attitude only (3)
    max_iter: int  # Gauss–Newton passes at most
    tol: float  # converged when every step component is below tol × its 1-σ


class Inputs(NamedTuple):
    """Data of all B trials (SI) and the epochs at which covariances are reported."""

    gyro: np.ndarray  # (B, N, 3) ω̃, rad/s
    ads_q: np.ndarray  # (B, N, 4) C_ADS, scalar-last
    ads_rate: np.ndarray  # (B, N, 3) ω_ADS, rad/s
    meas: np.ndarray  # (B, N) bool: an ADS measurement at the epoch
    slot: np.ndarray  # (N,) index of the epoch among the covariance epochs, −1 if none


class TrialData(NamedTuple):
    """The data of one trial: the rows of :class:`Inputs` for trial b."""

    gyro: np.ndarray  # (N, 3)
    ads_q: np.ndarray  # (N, 4)
    ads_rate: np.ndarray  # (N, 3)
    meas: np.ndarray  # (N,)
    slot: np.ndarray  # (N,)


class Outputs(NamedTuple):
    """Results of all B trials, written in place (SI)."""

    est: np.ndarray  # (B, N, 16): q̂_k, b̂ + β̂_k, p̂ per epoch
    cov: np.ndarray  # (B, M, 15, 15): error covariance at the sampled epochs
    info: np.ndarray  # (B, 4): passes, converged (0/1), χ² = Σ νᵀ S⁻¹ ν, measurement rows
    y: np.ndarray  # (B, 15): the unknowns [α, b, p] at the reported point
    cov_y: np.ndarray  # (B, 15, 15): their covariance
    step: np.ndarray  # (B, 15): the last Gauss–Newton step (not applied)


class Nuisance(NamedTuple):
    """Measurement model of the nuisance filter in scaled units (state ``[ξ/σ_a, β/e_r]``,
    rows ``[z_a/σ_a, z_r/e_r]``), filled by each forward pass."""

    hn: np.ndarray  # (m, 6) H̃
    r_t: np.ndarray  # (m, m) R̃


class PassStore(NamedTuple):
    """What the last forward pass keeps for the smoother (scaled units, 16 columns: the
    residual and the 15 Jacobian columns)."""

    q: np.ndarray  # (N, 4) Ĉ_k of the propagated attitude
    sens_s: np.ndarray  # (max(M, 1), 3, 15) S_k at the sampled epochs
    xz: np.ndarray  # (N, 6) filtered nuisance of the residual column
    pplus: np.ndarray  # (N, 6, 6) P⁺_k
    nu_all: np.ndarray  # (N, m, 16) innovations ν_k
    sinv_all: np.ndarray  # (N, m, m) S_k⁻¹
    gain_all: np.ndarray  # (N, 6, m) K_k
    fbar_all: np.ndarray  # (N, 6, 6) F̄_k, the decorrelated transition k → k+1
    xs: np.ndarray  # (max(M, 1), 6, 16) X⁺_k at the sampled epochs
