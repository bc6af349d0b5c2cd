r"""Transfer-alignment error model (docs/models.md), in numpy, batched over leading axes.

Gyro model and calibration vector::

    ω̃ = (I + K(p)) ω + b + η_v,     K(p) ω = Ω(ω) p,
    p = [s_x, s_y, s_z, k_xy, k_xz, k_yz, k_yx, k_zx, k_zy]

Rate estimate ``ω̂ = A (ω̃ − b̂)`` with ``A = (I + K(p̂))⁻¹``. Error state
``x = [δθ, Δb, Δp]`` (15), right-multiplicative attitude error ``C = Ĉ Exp(δθ)``::

    F = [[−[ω̂×], −A, −A Ω(ω̂)],        G Qc Gᵀ = blkdiag(σ_v² A Aᵀ, σ_u² I₃, q_p I₉)
         [  0,     0,     0    ],
         [  0,     0,     0    ]]

With ``ω̂`` held over a step of length ``Δt`` the transition is exact in closed form::

    Φ = [[R, −Γ A, −Γ A Ω], [0, I, 0], [0, 0, I]],
    R = Exp(−ω̂ Δt),   Γ = ∫₀^Δt Exp(−ω̂ s) ds = Δt · J(−ω̂ Δt)

and ``Q_d = ∫₀^Δt Φ(s) G Qc Gᵀ Φ(s)ᵀ ds`` reduces to three 3×3 integrals that are evaluated by
Gauss–Legendre quadrature. The integrands are trigonometric polynomials in ``s`` of frequency
at most ``2|ω̂|``, so the quadrature error is of order ``(|ω̂|Δt)^(2m)/(2m)!`` for ``m`` nodes:
machine precision at the rates of a calibration manoeuvre (checked against Van Loan's method
in the tests).

Measurements: attitude ``H_a = [I, 0, 0]``, ``R_a = σ_a² I``; angular rate
``H_r = [0, −A, −A Ω(ω̂)]``, ``R_r = σ_r² I + σ_v² A Aᵀ / Δt``.

All quantities SI: rad, rad/s, s; ``σ_v`` in rad/√s, ``σ_u`` in rad/s^1.5, ``q_p`` in 1/s.

This is the numpy reference. Compiled code (the filter kernel, the batch estimator) and the
methods that need the filter's own ``A``, ``Φ`` or attitude innovation use its compiled twin,
:mod:`qkf.transfer_alignment.model_compiled`; ``tests/test_model_compiled.py`` checks the two
against each other.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.linalg

from qkf.core.so3 import exp_matrix, left_jacobian, skew

N_STATES = 15
THETA = slice(0, 3)
BIAS = slice(3, 6)
CALIB = slice(6, 15)


def calibration_matrix(p: np.ndarray) -> np.ndarray:
    """``K(p)`` of calibration vectors (last axis 9, dimensionless); returns ``(..., 3, 3)``."""
    p = np.asarray(p, dtype=float)
    if p.shape[-1] != 9:
        raise ValueError(f"calibration vector needs 9 values, got shape {p.shape}")
    k = np.empty((*p.shape[:-1], 3, 3))
    k[..., 0, 0], k[..., 1, 1], k[..., 2, 2] = p[..., 0], p[..., 1], p[..., 2]
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = p[..., 3], p[..., 4], p[..., 5]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = p[..., 6], p[..., 7], p[..., 8]
    return k


def omega_matrix(w: np.ndarray) -> np.ndarray:
    """``Ω(ω)``, the 3×9 matrix with ``K(p) ω = Ω(ω) p``, for rates ``w`` (rad/s, last axis 3)."""
    w = np.asarray(w, dtype=float)
    out = np.zeros((*w.shape[:-1], 3, 9))
    out[..., 0, 0], out[..., 0, 3], out[..., 0, 4] = w[..., 0], w[..., 1], w[..., 2]
    out[..., 1, 1], out[..., 1, 5], out[..., 1, 6] = w[..., 1], w[..., 2], w[..., 0]
    out[..., 2, 2], out[..., 2, 7], out[..., 2, 8] = w[..., 2], w[..., 0], w[..., 1]
    return out


def rate_matrix(p_hat: np.ndarray) -> np.ndarray:
    """``A = (I + K(p̂))⁻¹`` (…, 3, 3) of calibration vectors ``p̂`` (…, 9): the map from the
    bias-corrected gyro output to the rate estimate."""
    return np.linalg.inv(np.eye(3) + calibration_matrix(p_hat))


def rate_estimate(
    gyro: np.ndarray, b_hat: np.ndarray, p_hat: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Corrected rate: returns ``(A, ω̂)`` with ``A = (I + K(p̂))⁻¹`` and ``ω̂ = A (ω̃ − b̂)``."""
    a = rate_matrix(p_hat)
    w_hat = np.einsum("...ij,...j->...i", a, np.asarray(gyro) - np.asarray(b_hat))
    return a, w_hat


def error_dynamics(w_hat: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Continuous error-dynamics matrix ``F`` (…, 15, 15) at rate ``ω̂`` and ``A``."""
    w_hat = np.asarray(w_hat, dtype=float)
    f = np.zeros((*w_hat.shape[:-1], N_STATES, N_STATES))
    f[..., THETA, THETA] = -skew(w_hat)
    f[..., THETA, BIAS] = -a
    f[..., THETA, CALIB] = -a @ omega_matrix(w_hat)
    return f


def process_noise_density(
    a: np.ndarray, sigma_v: float, sigma_u: float, q_p: np.ndarray | float
) -> np.ndarray:
    """``G Qc Gᵀ`` (…, 15, 15): ARW ``σ_v`` (rad/√s), RRW ``σ_u`` (rad/s^1.5), ``q_p`` (1/s)."""
    a = np.asarray(a, dtype=float)
    q_p = np.asarray(q_p, dtype=float)
    out = np.zeros((*a.shape[:-2], N_STATES, N_STATES))
    out[..., THETA, THETA] = sigma_v**2 * (a @ np.swapaxes(a, -1, -2))
    out[..., BIAS, BIAS] = sigma_u**2 * np.eye(3)
    out[..., CALIB, CALIB] = q_p[..., None, None] * np.eye(9)
    return out


@lru_cache(maxsize=16)
def gauss_legendre(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    return 0.5 * (x + 1.0), 0.5 * w


def attitude_transition(w_hat: np.ndarray, s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """``R(s) = Exp(−ω̂ s)`` and ``Γ(s) = ∫₀^s R(u) du``, for rates (rad/s) and times ``s`` (s).

    ``s`` broadcasts against the leading axes of ``w_hat``.
    """
    s = np.asarray(s, dtype=float)
    phi = -np.asarray(w_hat, dtype=float) * s[..., None]
    return exp_matrix(phi), s[..., None, None] * left_jacobian(phi)


def discretize(
    w_hat: np.ndarray,
    a: np.ndarray,
    dt: float,
    sigma_v: float,
    sigma_u: float,
    q_p: np.ndarray | float,
    nodes: int = 5,
    q_p_diag: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact discrete transition ``Φ`` and process noise ``Q_d`` (…, 15, 15) over ``dt`` (s).

    ``q_p`` (1/s) is one density for all nine calibration terms, per leading element;
    ``q_p_diag`` (…, 9), if given, sets each term's own density instead (``Qp = diag(q)``).
    ``Φ`` is closed form; ``Q_d`` uses ``nodes``-point Gauss–Legendre quadrature of its
    3×3 attitude integrals (see the module docstring).
    """
    w_hat = np.asarray(w_hat, dtype=float)
    a = np.asarray(a, dtype=float)
    lead = w_hat.shape[:-1]
    if q_p_diag is None:
        q_diag = np.broadcast_to(np.asarray(q_p, dtype=float)[..., None], (*lead, 9))
    else:
        q_diag = np.broadcast_to(np.asarray(q_p_diag, dtype=float), (*lead, 9))
    om = omega_matrix(w_hat)
    a_om = a @ om
    at = np.swapaxes(a, -1, -2)

    r_dt, g_dt = attitude_transition(w_hat, np.full(lead, dt))
    phi = np.broadcast_to(np.eye(N_STATES), (*lead, N_STATES, N_STATES)).copy()
    phi[..., THETA, THETA] = r_dt
    phi[..., THETA, BIAS] = -g_dt @ a
    phi[..., THETA, CALIB] = -g_dt @ a_om

    m1 = sigma_v**2 * (a @ at)
    om_q = om * q_diag[..., None, :]
    m2 = a @ (sigma_u**2 * np.eye(3) + om_q @ np.swapaxes(om, -1, -2)) @ at
    s_unit, w_unit = gauss_legendre(nodes)
    q_tt = np.zeros((*lead, 3, 3))
    gamma_int = np.zeros((*lead, 3, 3))
    for s_j, w_j in zip(s_unit * dt, w_unit * dt, strict=True):
        r_j, g_j = attitude_transition(w_hat, np.full(lead, s_j))
        q_tt += w_j * (r_j @ m1 @ np.swapaxes(r_j, -1, -2) + g_j @ m2 @ np.swapaxes(g_j, -1, -2))
        gamma_int += w_j * g_j

    qd = np.zeros((*lead, N_STATES, N_STATES))
    qd[..., THETA, THETA] = 0.5 * (q_tt + np.swapaxes(q_tt, -1, -2))
    q_tb = -(sigma_u**2) * (gamma_int @ a)
    q_tp = -(gamma_int @ a_om) * q_diag[..., None, :]
    qd[..., THETA, BIAS] = q_tb
    qd[..., BIAS, THETA] = np.swapaxes(q_tb, -1, -2)
    qd[..., THETA, CALIB] = q_tp
    qd[..., CALIB, THETA] = np.swapaxes(q_tp, -1, -2)
    qd[..., BIAS, BIAS] = sigma_u**2 * dt * np.eye(3)
    qd[..., CALIB, CALIB] = (q_diag * dt)[..., None, :] * np.eye(9)
    return phi, qd


def discretize_van_loan(f: np.ndarray, gqg: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Reference discretisation by Van Loan's matrix exponential (slow; for checks)."""
    n = f.shape[-1]
    m = np.zeros((*f.shape[:-2], 2 * n, 2 * n))
    m[..., :n, :n] = -f
    m[..., :n, n:] = gqg
    m[..., n:, n:] = np.swapaxes(f, -1, -2)
    e = scipy.linalg.expm(m * dt)
    phi = np.swapaxes(e[..., n:, n:], -1, -2)
    qd = phi @ e[..., :n, n:]
    return phi, 0.5 * (qd + np.swapaxes(qd, -1, -2))


def measurement_model(
    w_hat: np.ndarray,
    a: np.ndarray,
    dt: float,
    sigma_a: float,
    sigma_r: float,
    sigma_v: float,
    use_rate: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """``H`` (…, m, 15) and ``R`` (…, m, m); m = 3 (attitude) or 6 (attitude + rate).

    ``σ_a`` in rad, ``σ_r`` in rad/s, ``σ_v`` in rad/√s.
    """
    w_hat = np.asarray(w_hat, dtype=float)
    a = np.asarray(a, dtype=float)
    lead = w_hat.shape[:-1]
    m = 6 if use_rate else 3
    h = np.zeros((*lead, m, N_STATES))
    r = np.zeros((*lead, m, m))
    h[..., 0:3, THETA] = np.eye(3)
    r[..., 0:3, 0:3] = sigma_a**2 * np.eye(3)
    if use_rate:
        h[..., 3:6, BIAS] = -a
        h[..., 3:6, CALIB] = -a @ omega_matrix(w_hat)
        r[..., 3:6, 3:6] = sigma_r**2 * np.eye(3) + sigma_v**2 / dt * (a @ np.swapaxes(a, -1, -2))
    return h, r
