"""The error model against independent computations: finite differences of the nonlinear
propagation and measurement, Van Loan's method, scipy's rotations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.core import units
from qkf.core.so3 import exp_matrix, left_jacobian, rodrigues_coefficients
from qkf.transfer_alignment.model import (
    calibration_matrix,
    discretize,
    discretize_van_loan,
    error_dynamics,
    measurement_model,
    omega_matrix,
    process_noise_density,
    rate_estimate,
)

# state scales (prior sigmas) for comparing matrices in well-scaled units
D = np.array([60 * units.ARCSEC] * 3 + [2 * units.DEG_PER_H] * 3 + [1500 * units.PPM] * 9)
SIGMA_V = 4e-4 * units.DEG_PER_SQRT_H
SIGMA_U = 1e-3 * units.DEG_PER_H_1_5

ORBIT = np.array([0.0, -0.0607, 0.0]) * units.DEG_PER_S
RATES = {
    "rest": np.zeros(3),
    "orbit": ORBIT,
    "x_1deg_s": ORBIT + np.array([1.0, 0.0, 0.0]) * units.DEG_PER_S,
    "skew_1deg_s": ORBIT + np.array([0.6, -0.5, 0.62]) * units.DEG_PER_S,
}


@pytest.fixture
def nominal() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    return {
        "c_hat": Rotation.from_rotvec(rng.normal(size=3)).as_matrix(),
        "b_hat": rng.normal(0, 1.0, 3) * units.DEG_PER_H,
        "p_hat": rng.normal(0, 800, 9) * units.PPM,
    }


def test_omega_matrix_reproduces_calibration_product() -> None:
    rng = np.random.default_rng(0)
    p = rng.normal(size=(5, 9))
    w = rng.normal(size=(5, 3))
    lhs = np.einsum("bij,bj->bi", calibration_matrix(p), w)
    rhs = np.einsum("bij,bj->bi", omega_matrix(w), p)
    np.testing.assert_allclose(lhs, rhs, rtol=1e-14, atol=1e-14)
    k = calibration_matrix(np.arange(1.0, 10.0))
    # K(p) = [[s_x, k_xy, k_xz], [k_yx, s_y, k_yz], [k_zx, k_zy, s_z]]
    np.testing.assert_array_equal(k, [[1, 4, 5], [7, 2, 6], [8, 9, 3]])


def test_rotation_helpers_match_scipy() -> None:
    rng = np.random.default_rng(1)
    phi = rng.normal(size=(50, 3)) * np.logspace(-9, 0.4, 50)[:, None]
    np.testing.assert_allclose(exp_matrix(phi), Rotation.from_rotvec(phi).as_matrix(), atol=1e-14)
    a, b, c = rodrigues_coefficients(np.array([0.0, 1e-6, 0.05, 0.0999, 0.1001, 1.0]))
    t = np.array([1e-6, 0.05, 0.0999, 0.1001, 1.0])
    np.testing.assert_allclose(a[1:], np.sin(t) / t, rtol=1e-12)
    np.testing.assert_allclose(b[4:], (1 - np.cos(t[3:])) / t[3:] ** 2, rtol=1e-12)
    # c(θ) = (θ − sin θ)/θ³ by mpmath-free high precision: series to many terms
    ref = np.array(
        [
            sum((-1) ** k * x ** (2 * k) / np.prod(np.arange(1, 2 * k + 4)) for k in range(12))
            for x in t
        ]
    )
    np.testing.assert_allclose(c[1:], ref, rtol=1e-13)
    assert (a[0], b[0], c[0]) == (1.0, 0.5, pytest.approx(1 / 6))
    # left Jacobian = ∫₀¹ Exp(τφ) dτ by brute-force quadrature
    p1 = np.array([0.3, -0.2, 0.5])
    tau, w = np.polynomial.legendre.leggauss(30)
    brute = sum(wi * 0.5 * exp_matrix(0.5 * (ti + 1) * p1) for ti, wi in zip(tau, w, strict=True))
    np.testing.assert_allclose(left_jacobian(p1), brute, atol=1e-14)


def _true_rate(gyro: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.linalg.solve(np.eye(3) + calibration_matrix(p), gyro - b)


def _propagated_error(
    x: np.ndarray, nom: dict[str, np.ndarray], gyro: np.ndarray, h: float
) -> np.ndarray:
    """Nonlinear error after propagating truth and estimate over ``h`` seconds (noise-free)."""
    c_hat, b_hat, p_hat = nom["c_hat"], nom["b_hat"], nom["p_hat"]
    c_true = c_hat @ Rotation.from_rotvec(x[0:3]).as_matrix()
    w_true = _true_rate(gyro, b_hat + x[3:6], p_hat + x[6:15])
    w_hat = _true_rate(gyro, b_hat, p_hat)
    c_true_next = c_true @ Rotation.from_rotvec(w_true * h).as_matrix()
    c_hat_next = c_hat @ Rotation.from_rotvec(w_hat * h).as_matrix()
    dtheta = Rotation.from_matrix(c_hat_next.T @ c_true_next).as_rotvec()
    return np.concatenate([dtheta, x[3:15]])


def _jacobian_fd(fun, n: int = 15, rel: float = 1e-3) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Central differences in the scaled coordinates x = D x̃; returns the Jacobian in SI."""
    cols = []
    for j in range(n):
        e = np.zeros(n)
        e[j] = rel * D[j]
        cols.append((fun(e) - fun(-e)) / (2 * e[j]))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("name", list(RATES))
def test_F_matches_finite_differences_of_nonlinear_propagation(name, nominal) -> None:  # type: ignore[no-untyped-def]
    w_true = RATES[name]
    gyro = (np.eye(3) + calibration_matrix(nominal["p_hat"])) @ w_true + nominal["b_hat"]
    a, w_hat = rate_estimate(gyro, nominal["b_hat"], nominal["p_hat"])
    f = error_dynamics(w_hat, a)
    h = 1e-3
    # Φ(h) − Φ(−h) = 2 h F + O(h³): the derivative of the flow at t = 0
    fd = (
        _jacobian_fd(lambda x: _propagated_error(x, nominal, gyro, h))
        - _jacobian_fd(lambda x: _propagated_error(x, nominal, gyro, -h))
    ) / (2 * h)
    scaled = lambda m: m * D[None, :] / D[:, None]  # noqa: E731
    np.testing.assert_allclose(scaled(fd), scaled(f), atol=1e-6)


@pytest.mark.parametrize("name", list(RATES))
def test_closed_form_phi_is_the_exact_one_step_jacobian(name, nominal) -> None:  # type: ignore[no-untyped-def]
    w_true = RATES[name]
    gyro = (np.eye(3) + calibration_matrix(nominal["p_hat"])) @ w_true + nominal["b_hat"]
    a, w_hat = rate_estimate(gyro, nominal["b_hat"], nominal["p_hat"])
    dt = 1.0
    phi, _ = discretize(w_hat, a, dt, SIGMA_V, SIGMA_U, 1e-14)
    fd = _jacobian_fd(lambda x: _propagated_error(x, nominal, gyro, dt))
    scaled = lambda m: m * D[None, :] / D[:, None]  # noqa: E731
    np.testing.assert_allclose(scaled(fd), scaled(phi), atol=1e-7)
    # and it is not the first-order I + FΔt during a rotation
    if np.linalg.norm(w_hat) > 0.01:
        first_order = np.eye(15) + error_dynamics(w_hat, a) * dt
        assert np.max(np.abs(scaled(first_order) - scaled(phi))) > 1e-5


@pytest.mark.parametrize("rate_deg_s", [0.0, 0.06, 1.0, 10.0, 30.0])
@pytest.mark.parametrize("q_p", [1e-20, 1e-14, 1e-10])
def test_discretisation_matches_van_loan(rate_deg_s: float, q_p: float) -> None:
    rng = np.random.default_rng(3)
    w = rng.normal(size=3)
    w *= rate_deg_s * units.DEG_PER_S / max(np.linalg.norm(w), 1e-300)
    a = np.linalg.inv(np.eye(3) + calibration_matrix(rng.normal(0, 1e-3, 9)))
    dt = 1.0
    phi, qd = discretize(w, a, dt, SIGMA_V, SIGMA_U, q_p, nodes=6)
    phi_vl, qd_vl = discretize_van_loan(
        error_dynamics(w, a), process_noise_density(a, SIGMA_V, SIGMA_U, q_p), dt
    )
    np.testing.assert_allclose(phi, phi_vl, rtol=0, atol=1e-11)
    # compare Q in units where its diagonal is one
    s = np.sqrt(np.diag(qd_vl))
    np.testing.assert_allclose(qd / np.outer(s, s), qd_vl / np.outer(s, s), rtol=0, atol=1e-10)
    assert np.all(np.linalg.eigvalsh(qd / np.outer(s, s)) > -1e-12)


def test_per_term_process_noise_matches_van_loan() -> None:
    rng = np.random.default_rng(6)
    w = np.array([0.3, -0.8, 0.5]) * units.DEG_PER_S
    a = np.linalg.inv(np.eye(3) + calibration_matrix(rng.normal(0, 1e-3, 9)))
    q = 10.0 ** rng.uniform(-16, -10, 9)
    _, qd = discretize(w, a, 1.0, SIGMA_V, SIGMA_U, 0.0, q_p_diag=q)
    gqg = process_noise_density(a, SIGMA_V, SIGMA_U, 0.0)
    gqg[6:, 6:] = np.diag(q)
    _, qd_vl = discretize_van_loan(error_dynamics(w, a), gqg, 1.0)
    s = np.sqrt(np.diag(qd_vl))
    np.testing.assert_allclose(qd / np.outer(s, s), qd_vl / np.outer(s, s), atol=1e-10)


def test_discretisation_is_batched_over_leading_axes() -> None:
    rng = np.random.default_rng(4)
    w = rng.normal(0, 0.02, (4, 2, 3))
    a = np.linalg.inv(np.eye(3) + calibration_matrix(rng.normal(0, 1e-3, (4, 2, 9))))
    q_p = np.full((4, 2), 1e-14)
    phi, qd = discretize(w, a, 1.0, SIGMA_V, SIGMA_U, q_p)
    phi1, qd1 = discretize(w[2, 1], a[2, 1], 1.0, SIGMA_V, SIGMA_U, 1e-14)
    np.testing.assert_array_equal(phi[2, 1], phi1)
    np.testing.assert_array_equal(qd[2, 1], qd1)


@pytest.mark.parametrize("name", ["rest", "skew_1deg_s"])
def test_rate_measurement_jacobian_matches_finite_differences(name, nominal) -> None:  # type: ignore[no-untyped-def]
    w_true = RATES[name]
    gyro = (np.eye(3) + calibration_matrix(nominal["p_hat"])) @ w_true + nominal["b_hat"]
    a, w_hat = rate_estimate(gyro, nominal["b_hat"], nominal["p_hat"])
    h, r = measurement_model(w_hat, a, 1.0, 3 * units.ARCSEC, 0.02 * units.DEG_PER_H, SIGMA_V, True)

    def z(x: np.ndarray) -> np.ndarray:
        # noise-free: C_ADS = C_true, ω_ADS = ω_true
        za = x[0:3]  # Log(Ĉᵀ Ĉ Exp(δθ))
        zr = _true_rate(gyro, nominal["b_hat"] + x[3:6], nominal["p_hat"] + x[6:15]) - w_hat
        return np.concatenate([za, zr])

    fd = _jacobian_fd(z)
    np.testing.assert_allclose(fd * D[None, :], h * D[None, :], atol=1e-12)
    assert r.shape == (6, 6)
    np.testing.assert_allclose(r[3:, 3:], r[3:, 3:].T)
    np.testing.assert_allclose(
        r[3:, 3:], (0.02 * units.DEG_PER_H) ** 2 * np.eye(3) + SIGMA_V**2 * a @ a.T, rtol=1e-12
    )
