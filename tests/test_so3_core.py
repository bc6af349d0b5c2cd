"""The rotation core: every routine of the compiled twin (qkf.core.quat) against the numpy one
(qkf.core.so3) and both against scipy.spatial.transform.Rotation, at small angles, at the
series/closed-form switch points, up to π, on batches and on random draws with a fixed seed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.core import quat, so3
from tests.conftest import align_quat_sign

# angles (rad) at which the formulas switch branches, plus tiny, ordinary and extreme ones
ANGLES = [0.0, 1e-12, 1e-8, 9.99e-5, 1e-4, 1.001e-4, 1e-3, 0.05, 0.0999, 0.1, 0.1001, 0.5, 1.0]
ANGLES += [2.0, 3.0, np.pi - 1e-6]


def _rotvecs(seed: int = 11) -> np.ndarray:
    """Rotation vectors with the angles of ``ANGLES`` along random axes, then random draws."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(len(ANGLES), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    fixed = axes * np.array(ANGLES)[:, None]
    drawn = rng.normal(size=(40, 3)) * np.logspace(-9, 0.45, 40)[:, None]
    return np.concatenate([fixed, drawn])


def _rotations(seed: int = 12, n: int = 30) -> np.ndarray:
    """Random unit quaternions (scalar-last), both signs of w."""
    q = Rotation.random(n, random_state=seed).as_quat()
    q[::3] *= -1.0
    return q


# ---- Rodrigues coefficients, skew, Exp and the left Jacobian -----------------------------------


def _series_c(t: float) -> float:
    """(θ − sin θ)/θ³ by its alternating series (no cancellation)."""
    return math.fsum((-1) ** k * t ** (2 * k) / math.factorial(2 * k + 3) for k in range(40))


@pytest.mark.parametrize("theta", ANGLES)
def test_rodrigues_coefficients_compiled_numpy_and_closed_forms(theta: float) -> None:
    a, b, c = quat.rodrigues_coefficients(theta)
    a_np, b_np, c_np = so3.rodrigues_coefficients(np.array(theta))
    np.testing.assert_allclose([a, b, c], [a_np, b_np, c_np], rtol=2e-15, atol=0)
    if theta > 1e-3:  # the closed forms are accurate there
        np.testing.assert_allclose(a, np.sin(theta) / theta, rtol=1e-15)
        np.testing.assert_allclose(b, 2.0 * np.sin(theta / 2) ** 2 / theta**2, rtol=1e-15)
    # just above the switch at 0.1 rad the closed form of c loses ~2 digits to cancellation
    np.testing.assert_allclose(c, _series_c(theta), rtol=1e-13)
    if theta == 0.0:
        assert (a, b) == (1.0, 0.5)
        assert c == pytest.approx(1.0 / 6.0, rel=1e-16)


def test_skew_and_square_against_numpy_and_the_cross_product() -> None:
    rng = np.random.default_rng(3)
    w_mat, w2 = np.empty((3, 3)), np.empty((3, 3))
    for w in rng.normal(size=(20, 3)):
        quat.skew_and_square(w, w_mat, w2)
        np.testing.assert_array_equal(w_mat, so3.skew(w))
        np.testing.assert_allclose(w2, so3.skew(w) @ so3.skew(w), rtol=1e-15, atol=1e-16)
        v = rng.normal(size=3)
        np.testing.assert_allclose(w_mat @ v, np.cross(w, v), rtol=1e-14, atol=1e-15)


def test_exp_and_left_jacobian_against_numpy_and_scipy() -> None:
    phis = _rotvecs()
    rot, jac = np.empty((3, 3)), np.empty((3, 3))
    ref_rot = Rotation.from_rotvec(phis).as_matrix()
    np_rot, np_jac = so3.exp_matrix(phis), so3.left_jacobian(phis)
    np.testing.assert_allclose(np_rot, ref_rot, atol=2e-15)
    for i, phi in enumerate(phis):
        quat.exp_and_left_jacobian(phi, rot, jac)
        np.testing.assert_allclose(rot, np_rot[i], atol=2e-15)
        np.testing.assert_allclose(rot, ref_rot[i], atol=2e-15)
        np.testing.assert_allclose(jac, np_jac[i], atol=2e-15)
    # J_l(φ) = ∫₀¹ Exp(τφ) dτ, by Gauss–Legendre quadrature of scipy's rotations
    tau, w = np.polynomial.legendre.leggauss(30)
    for phi in (np.array([0.3, -0.2, 0.5]), np.array([1e-7, 2e-7, -1e-7]), np.array([2.0, 1, 0])):
        quat.exp_and_left_jacobian(phi, rot, jac)
        brute = sum(
            wi * 0.5 * Rotation.from_rotvec(0.5 * (ti + 1) * phi).as_matrix()
            for ti, wi in zip(tau, w, strict=True)
        )
        np.testing.assert_allclose(jac, brute, atol=1e-14)


# ---- quaternions ---------------------------------------------------------------------------------


def test_quat_mul_compiled_numpy_and_scipy() -> None:
    p, q = _rotations(1), _rotations(2)
    ref = (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat()
    batch = so3.quat_mul(p, q)  # batched over the leading axis
    np.testing.assert_allclose(align_quat_sign(batch, ref), ref, atol=1e-15)
    out = np.empty(4)
    for i in range(p.shape[0]):
        quat.quat_mul(p[i], q[i], out)
        np.testing.assert_allclose(out, batch[i], rtol=0, atol=1e-16)
    # broadcasting: one quaternion against a batch
    np.testing.assert_allclose(so3.quat_mul(p[0], q), so3.quat_mul(np.tile(p[0], (30, 1)), q))


def test_quat_conj_is_scipys_inverse() -> None:
    q = _rotations(4)
    ref = Rotation.from_quat(q).inv().as_matrix()
    np.testing.assert_allclose(Rotation.from_quat(so3.quat_conj(q)).as_matrix(), ref, atol=1e-15)


def test_quat_exp_compiled_numpy_and_scipy() -> None:
    phis = _rotvecs()
    ref = Rotation.from_rotvec(phis).as_quat()
    batch = so3.quat_exp(phis)
    np.testing.assert_allclose(align_quat_sign(batch, ref), ref, atol=2e-16)
    out = np.empty(4)
    for i, phi in enumerate(phis):
        quat.quat_from_rotvec(phi, out)
        np.testing.assert_allclose(out, batch[i], rtol=0, atol=2e-16)
    np.testing.assert_allclose(np.linalg.norm(batch, axis=1), 1.0, rtol=0, atol=4e-16)


def test_quat_log_compiled_numpy_and_scipy() -> None:
    phis = _rotvecs()
    q = Rotation.from_rotvec(phis).as_quat()
    q[::2] *= -1.0  # q and −q are one rotation
    batch = so3.quat_log(q)
    below_pi = np.linalg.norm(phis, axis=1) < 3.0  # near π the axis sign is ambiguous
    np.testing.assert_allclose(batch[below_pi], phis[below_pi], rtol=1e-13, atol=1e-20)
    np.testing.assert_allclose(
        Rotation.from_rotvec(batch).as_matrix(), Rotation.from_quat(q).as_matrix(), atol=2e-15
    )
    out = np.empty(3)
    for i in range(q.shape[0]):
        quat.rotvec_from_quat(q[i], out)
        np.testing.assert_allclose(out, batch[i], rtol=1e-15, atol=1e-22)
    # the angle is in [0, π]
    assert np.all(np.linalg.norm(batch, axis=1) <= np.pi)


def test_quat_log_at_pi_and_identity() -> None:
    out = np.empty(3)
    half_turn = np.array([0.0, 0.0, 1.0, 0.0])  # π about z
    quat.rotvec_from_quat(half_turn, out)
    np.testing.assert_allclose(out, [0.0, 0.0, np.pi], rtol=1e-15)
    np.testing.assert_allclose(so3.quat_log(half_turn), [0.0, 0.0, np.pi], rtol=1e-15)
    quat.rotvec_from_quat(np.array([0.0, 0.0, 0.0, -1.0]), out)
    np.testing.assert_array_equal(out, 0.0)
    np.testing.assert_array_equal(so3.quat_log(np.array([0.0, 0.0, 0.0, 1.0])), 0.0)


def test_relative_rotvec_is_the_log_of_the_conjugate_product() -> None:
    p, q = _rotations(5), _rotations(6)
    rel = (Rotation.from_quat(p).inv() * Rotation.from_quat(q)).as_rotvec()
    batch = so3.quat_log(so3.quat_mul(so3.quat_conj(p), q))
    np.testing.assert_allclose(batch, rel, rtol=1e-12, atol=1e-14)
    out = np.empty(3)
    for i in range(p.shape[0]):
        quat.relative_rotvec(p[i], q[i], out)
        np.testing.assert_allclose(out, batch[i], rtol=1e-15, atol=1e-16)
    # small relative rotations, as between an estimate and the ADS (arcseconds)
    delta = np.random.default_rng(7).normal(size=(30, 3)) * 1e-5
    q2 = (Rotation.from_quat(p) * Rotation.from_rotvec(delta)).as_quat()
    for i in range(p.shape[0]):
        quat.relative_rotvec(p[i], q2[i], out)
        np.testing.assert_allclose(out, delta[i], rtol=1e-9, atol=1e-20)


def test_quat_mul_exp_is_the_right_perturbation_normalised() -> None:
    q, phis = _rotations(8, 56), _rotvecs()
    assert q.shape[0] == phis.shape[0]
    ref = (Rotation.from_quat(q) * Rotation.from_rotvec(phis)).as_quat()
    np_ref = so3.quat_mul(q, so3.quat_exp(phis))
    np_ref /= np.linalg.norm(np_ref, axis=1, keepdims=True)
    np.testing.assert_allclose(align_quat_sign(np_ref, ref), ref, atol=1e-15)
    out = np.empty(4)
    for i in range(q.shape[0]):
        quat.quat_mul_exp(q[i], phis[i], out)
        np.testing.assert_allclose(out, np_ref[i], rtol=0, atol=2e-16)
        assert abs(np.linalg.norm(out) - 1.0) < 4e-16
        in_place = q[i].copy()  # out may be q
        quat.quat_mul_exp(in_place, phis[i], in_place)
        np.testing.assert_array_equal(in_place, out)


def test_normalize_and_cumulative_rotation() -> None:
    q = np.array([1.0, 2.0, 3.0, 4.0])
    quat.normalize(q)
    np.testing.assert_allclose(q, np.array([1.0, 2.0, 3.0, 4.0]) / np.sqrt(30.0), rtol=1e-15)
    q0 = _rotations(9, 1)[0]
    steps = np.random.default_rng(10).normal(size=(500, 3)) * 0.02
    path = quat.cumulative_rotation(q0, steps)
    ref = Rotation.from_quat(q0)
    for k in range(steps.shape[0]):
        ref = ref * Rotation.from_rotvec(steps[k])
    np.testing.assert_allclose(
        Rotation.from_quat(path[-1]).as_matrix(), ref.as_matrix(), atol=1e-13
    )
    np.testing.assert_array_equal(path[0], q0)
    # the same steps one at a time
    step = q0.copy()
    for k in range(3):
        quat.quat_mul_exp(step, steps[k], step)
    np.testing.assert_array_equal(step, path[3])


def test_attitude_error_rows_match_numpy_and_scipy() -> None:
    """``quat.attitude_error_into`` (the compiled error metric) equals ``Log(q̂* ⊗ q)`` of the
    normalised quaternions in numpy and scipy's relative rotation, for unnormalised inputs,
    both signs, small and large relative angles; rows with a non-finite side are NaN and do
    not touch the others."""
    rng = np.random.default_rng(5)
    phi = _rotvecs(22)
    m = phi.shape[0]
    q_from = _rotations(21, m) * rng.uniform(0.5, 2.0, size=(m, 1))  # not unit length
    q_to = np.array([so3.quat_mul(q, so3.quat_exp(p)) for q, p in zip(q_from, phi, strict=True)])
    q_to[1::2] *= -rng.uniform(0.5, 2.0, size=(q_to[1::2].shape[0], 1))  # other sign, scale
    q_from[7, 2] = np.nan
    q_to[11, 0] = np.inf
    out = np.empty((m, 3))
    quat.attitude_error_into(q_from, q_to, out)
    bad = np.zeros(m, dtype=bool)
    bad[[7, 11]] = True
    assert np.isnan(out[bad]).all() and np.isfinite(out[~bad]).all()
    a = q_from[~bad] / np.linalg.norm(q_from[~bad], axis=1, keepdims=True)
    b = q_to[~bad] / np.linalg.norm(q_to[~bad], axis=1, keepdims=True)
    expect = so3.quat_log(so3.quat_mul(so3.quat_conj(a), b))
    np.testing.assert_allclose(out[~bad], expect, rtol=1e-14, atol=1e-18)
    inside = ~bad & (np.linalg.norm(phi, axis=1) < 3.0)  # Log gives angles in [0, π]
    np.testing.assert_allclose(out[inside], phi[inside], rtol=1e-9, atol=1e-12)
    scipy_rel = (Rotation.from_quat(a).inv() * Rotation.from_quat(b)).as_rotvec()
    np.testing.assert_allclose(out[~bad], scipy_rel, rtol=1e-12, atol=1e-15)


def test_attitude_error_is_scipys_relative_rotation() -> None:
    """``quat.attitude_error(q̂, q)`` is scipy's ``(R(q̂)⁻¹ R(q)).as_rotvec()`` to 1e-12 relative
    (1e-15 rad absolute: a quaternion holds an attitude to ~1e-16 rad) for random pairs at
    relative angles from 1e-9 rad to within 1e-9 rad of π, both signs of w on either side, any
    length; the half turn itself up to the sign of its axis."""
    rng = np.random.default_rng(17)
    m = 500
    near_pi = np.pi - np.array([1e-2, 1e-3, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9])
    angle = np.concatenate([10.0 ** rng.uniform(-9, 0.49, m - near_pi.size), near_pi])
    axis = rng.normal(size=(m, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    q_hat = Rotation.random(m, random_state=rng).as_quat()
    q = (Rotation.from_quat(q_hat) * Rotation.from_rotvec(axis * angle[:, None])).as_quat()
    q_hat[::2] *= -1.0  # q and −q are one rotation
    q[1::3] *= -1.0
    q_hat *= rng.uniform(0.3, 3.0, size=(m, 1))  # not unit length
    q *= rng.uniform(0.3, 3.0, size=(m, 1))
    want = (Rotation.from_quat(q_hat).inv() * Rotation.from_quat(q)).as_rotvec()
    got = quat.attitude_error(q_hat, q)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), angle, rtol=1e-9, atol=1e-15)
    # exact half turns: Exp(δθ) = Ĉᵀ C, angle π
    q_pi = so3.quat_mul(q_hat[:20], so3.quat_exp(axis[:20] * np.pi))
    half = quat.attitude_error(q_hat[:20], q_pi)
    rel = Rotation.from_quat(q_hat[:20]).inv() * Rotation.from_quat(q_pi)
    np.testing.assert_allclose(np.linalg.norm(half, axis=1), np.pi, rtol=1e-12)
    np.testing.assert_allclose(
        Rotation.from_rotvec(half).as_matrix(), rel.as_matrix(), rtol=0, atol=1e-12
    )


def test_attitude_error_over_leading_axes() -> None:
    """Any leading axes, broadcast against each other, row for row the compiled kernel; NaN
    where either side is not finite; a last axis other than 4 is refused."""
    q_hat, q = _rotations(31, 24).reshape(2, 3, 4, 4), _rotations(32, 24).reshape(2, 3, 4, 4)
    got = quat.attitude_error(q_hat[:, :1], q)  # (2, 1, 4, 4) against (2, 3, 4, 4)
    rows = np.empty((24, 3))
    quat.attitude_error_into(
        np.broadcast_to(q_hat[:, :1], q.shape).reshape(-1, 4), q.reshape(-1, 4), rows
    )
    assert got.shape == (2, 3, 4, 3)
    np.testing.assert_array_equal(got, rows.reshape(2, 3, 4, 3))
    np.testing.assert_array_equal(quat.attitude_error(q_hat[1, 0, 3], q[1, 2, 3]), got[1, 2, 3])
    q[0, 1, 2, 3] = np.nan
    with_nan = quat.attitude_error(q_hat[:, :1], q)
    assert np.isnan(with_nan[0, 1, 2]).all()
    finite = np.ones(got.shape[:-1], dtype=bool)
    finite[0, 1, 2] = False
    np.testing.assert_array_equal(with_nan[finite], got[finite])
    with pytest.raises(ValueError, match="last axis of 4"):
        quat.attitude_error(np.zeros((5, 3)), np.zeros((5, 3)))


def test_compose_rotvecs_matches_scipy_composition() -> None:
    """``quat.compose_rotvecs`` (how the simulator draws ADS attitudes) equals scipy's
    ``from_quat(q) * from_rotvec(φ)`` for unnormalised q and angles on both sides of the
    Taylor switch (1e-3 rad) up to π; same sign convention (no flip of the hemisphere)."""
    rng = np.random.default_rng(9)
    m = 5000
    q = Rotation.random(m, random_state=3).as_quat() * rng.uniform(0.8, 1.2, size=(m, 1))
    phi = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-9, 0.2, size=(m, 1))
    phi[:4] = [[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, 1.0001e-3, 0.0], [0.0, 0.0, 3.0]]
    out = np.empty((m, 4))
    quat.compose_rotvecs(q, phi, out)
    expect = (Rotation.from_quat(q) * Rotation.from_rotvec(phi)).as_quat()
    np.testing.assert_allclose(out, expect, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-15)
