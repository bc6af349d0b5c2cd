"""The compiled transfer-alignment model (qkf.transfer_alignment.model_compiled) against the
numpy reference (qkf.transfer_alignment.model) and scipy: A and ω̂, the Ω index tables, A Ω,
the rate rows of H, R(s) and Γ(s), the rows of Φ (scaled and in SI), the attitude residual; and
that the filter kernel computes exactly these numbers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.core import units
from qkf.core.quat import skew_and_square
from qkf.transfer_alignment import model
from qkf.transfer_alignment import model_compiled as mc
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with

ORBIT = np.array([0.0, -0.0607, 0.0]) * units.DEG_PER_S
RATES = {
    "rest": np.zeros(3),
    "orbit": ORBIT,
    "x_1deg_s": ORBIT + np.array([1.0, 0.0, 0.0]) * units.DEG_PER_S,
    "skew_10deg_s": np.array([6.0, -5.0, 6.2]) * units.DEG_PER_S,
    "fast_0.3rad_s": np.array([0.2, -0.1, 0.2]),  # |ω̂|Δt > 0.1 rad: closed-form Rodrigues
}
D = np.array([60 * units.ARCSEC] * 3 + [2 * units.DEG_PER_H] * 3 + [1500 * units.PPM] * 9)


def _draws(seed: int, n: int, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro outputs (rad/s), biases (rad/s) and calibrations of n random cases."""
    rng = np.random.default_rng(seed)
    gyro = rng.normal(size=(n, 3)) * 0.02
    b = rng.normal(size=(n, 3)) * 1e-5
    p = rng.normal(size=(n, 9)) * scale
    return gyro, b, p


@pytest.mark.parametrize("scale", [1e-3, 0.1])
def test_rate_estimate_is_the_models(scale: float) -> None:
    gyro, b, p = _draws(1, 30, scale)
    a_ref, w_ref = model.rate_estimate(gyro, b, p)
    np.testing.assert_array_equal(a_ref, model.rate_matrix(p))
    a, w = np.empty((3, 3)), np.empty(3)
    for i in range(gyro.shape[0]):
        assert mc.rate_estimate(gyro[i], b[i], p[i], a, w)
        np.testing.assert_allclose(a, a_ref[i], rtol=1e-14, atol=1e-15)
        # ω̂ = A (g − b): a component can be a difference of terms ~1e3 times its size, so
        # its rounding is relative to the terms (|g| ~ 0.02 rad/s), not to itself; with and
        # without fused multiply-adds (numba compiled for a generic CPU) the smallest component
        # moved by 1e-19 = 1.4e-14 of itself. atol: about 10 ulps of the terms
        np.testing.assert_allclose(w, w_ref[i], rtol=1e-14, atol=1e-15 * np.abs(gyro[i]).max())
        np.testing.assert_allclose((np.eye(3) + model.calibration_matrix(p[i])) @ a, np.eye(3),
                                   atol=1e-15)  # fmt: skip


def test_rate_estimate_refuses_a_singular_or_non_finite_calibration() -> None:
    a, w = np.full((3, 3), 7.0), np.full(3, 7.0)
    singular = np.zeros(9)
    singular[0] = -1.0  # 1 + s_x = 0
    assert not mc.rate_estimate(np.ones(3), np.zeros(3), singular, a, w)
    nan_p = np.zeros(9)
    nan_p[4] = np.nan
    assert not mc.rate_estimate(np.ones(3), np.zeros(3), nan_p, a, w)
    np.testing.assert_array_equal(a, 7.0)  # untouched
    np.testing.assert_array_equal(w, 7.0)


def test_omega_tables_and_a_omega_are_the_models() -> None:
    rng = np.random.default_rng(2)
    w, p = rng.normal(size=3), rng.normal(size=9) * 1e-3
    om = np.zeros((3, 9))
    om[mc.OM_ROW, np.arange(9)] = w[mc.OM_COL]  # column l: ω[OM_COL[l]] in row OM_ROW[l]
    np.testing.assert_array_equal(om, model.omega_matrix(w))
    np.testing.assert_allclose(om @ p, model.calibration_matrix(p) @ w, rtol=1e-14)
    a = model.rate_matrix(p)
    out = np.empty((3, 9))
    mc.a_omega(a, w, out)
    np.testing.assert_allclose(out, a @ model.omega_matrix(w), rtol=1e-15, atol=0)


def test_rate_jacobian_is_the_rate_rows_of_h() -> None:
    gyro, b, p = _draws(3, 5, 1e-3)
    a_ref, w_ref = model.rate_estimate(gyro, b, p)
    h, _ = model.measurement_model(w_ref, a_ref, 1.0, 1e-5, 1e-7, 1e-7, use_rate=True)
    out = np.empty((3, 15))
    for i in range(5):
        mc.rate_jacobian(a_ref[i], w_ref[i], out)
        np.testing.assert_allclose(out, h[i, 3:6], rtol=1e-15, atol=0)


@pytest.mark.parametrize("name", list(RATES))
@pytest.mark.parametrize("s", [0.0, 0.3, 1.0])
def test_attitude_transition_is_the_models(name: str, s: float) -> None:
    w = RATES[name]
    wx, wx2, r, g = (np.empty((3, 3)) for _ in range(4))
    skew_and_square(-w, wx, wx2)
    mc.attitude_transition(wx, wx2, float(np.linalg.norm(w)), s, r, g)
    r_ref, g_ref = model.attitude_transition(w, s)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=2e-15)
    np.testing.assert_allclose(g, g_ref, rtol=0, atol=2e-15)
    np.testing.assert_allclose(r, Rotation.from_rotvec(-w * s).as_matrix(), atol=2e-15)


@pytest.mark.parametrize("name", list(RATES))
def test_phi_rows_scaled_and_in_si_are_the_models(name: str) -> None:
    w = RATES[name]
    p = np.random.default_rng(4).normal(size=9) * 1e-3
    dt = 1.0
    a = model.rate_matrix(p)
    phi_ref, _ = model.discretize(w, a, dt, 1e-7, 1e-9, 1e-14)
    wx, wx2, rr, gg = (np.empty((3, 3)) for _ in range(4))
    aom = np.empty((3, 9))
    skew_and_square(-w, wx, wx2)
    mc.attitude_transition(wx, wx2, float(np.linalg.norm(w)), dt, rr, gg)
    mc.a_omega(a, w, aom)
    top = np.empty((3, 15))
    mc.phi_top_rows(rr, gg, a, aom, np.ones((3, 15)), top)
    np.testing.assert_allclose(top, phi_ref[0:3], rtol=1e-13, atol=1e-17)
    ratio = D[None, :] / D[0:3, None]  # Φ̃ = D⁻¹ Φ D
    mc.phi_top_rows(rr, gg, a, aom, ratio, top)
    scaled_ref = (phi_ref * D[None, :] / D[:, None])[0:3]
    np.testing.assert_allclose(top, scaled_ref, rtol=1e-13, atol=1e-15)
    # the batched wrapper, with leading axes
    phi = mc.transition_matrix(np.broadcast_to(w, (2, 2, 3)), p, dt)
    assert phi.shape == (2, 2, 15, 15)
    np.testing.assert_allclose(phi[1, 0], phi_ref, rtol=1e-13, atol=1e-17)


def test_transition_matrix_marks_a_singular_calibration() -> None:
    p = np.zeros((2, 9))
    p[1, 1] = -1.0  # 1 + s_y = 0
    phi = mc.transition_matrix(np.full((2, 3), 0.01), p, 1.0)
    assert np.all(np.isfinite(phi[0]))
    assert np.all(np.isnan(phi[1, 0:3]))
    np.testing.assert_array_equal(phi[1, 3:], np.eye(15)[3:])


def test_attitude_innovation_is_scipys_log_and_the_kernels_bit_for_bit() -> None:
    q_hat = Rotation.random(20, random_state=3).as_quat()
    delta = np.random.default_rng(5).normal(size=(20, 3)) * 1e-4
    ads = (Rotation.from_quat(q_hat) * Rotation.from_rotvec(delta)).as_quat()
    ads[::2] *= -1.0  # either sign of the ADS quaternion
    nu = mc.attitude_innovation(q_hat, ads)
    ref = (Rotation.from_quat(q_hat).inv() * Rotation.from_quat(ads)).as_rotvec()
    np.testing.assert_allclose(nu, ref, rtol=1e-10, atol=1e-20)
    np.testing.assert_allclose(nu, delta, rtol=1e-9)
    assert mc.attitude_innovation(q_hat[None], ads[None]).shape == (1, 20, 3)
    # the kernel forms its innovation with the same routine: equal to the last bit
    cfg = cfg_with("scenario.duration_s=30")
    data = simulate(cfg, 2, 3)
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 3)
    kf.initialize(data.ads_q[:, 0])
    for k in range(12):
        expected = mc.attitude_innovation(kf.q_hat, data.ads_q[:, k])
        rec = kf.step_data(data, k, k + 1)
        np.testing.assert_array_equal(rec.innov[:, 0, 0:3], expected)
