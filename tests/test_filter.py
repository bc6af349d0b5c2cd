"""The compiled transfer-alignment filter against the plain filterpy/scipy reference, and its
handling of bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.core import quat
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.reference import run_reference
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import align_quat_sign, cfg_with


def test_quaternion_helpers_match_scipy() -> None:
    rng = np.random.default_rng(5)
    for angle in (1e-10, 1e-5, 1e-2, 1.0, 3.1):
        phi = rng.normal(size=3)
        phi *= angle / np.linalg.norm(phi)  # angles below π: Log returns them unchanged
        out = np.empty(4)
        quat.quat_from_rotvec(phi, out)
        ref = Rotation.from_rotvec(phi).as_quat()
        np.testing.assert_allclose(align_quat_sign(out, ref), ref, atol=1e-15)
        back = np.empty(3)
        quat.rotvec_from_quat(ref, back)
        np.testing.assert_allclose(back, phi, rtol=1e-12, atol=1e-18)
        quat.rotvec_from_quat(-ref, back)  # the same rotation
        np.testing.assert_allclose(back, phi, rtol=1e-12, atol=1e-18)
    p, q = Rotation.random(2, random_state=1)
    out = np.empty(4)
    quat.quat_mul(p.as_quat(), q.as_quat(), out)
    ref = (p * q).as_quat()
    np.testing.assert_allclose(align_quat_sign(out, ref), ref, atol=1e-15)


@pytest.mark.parametrize("matching", ["attitude", "attitude_rate"])
@pytest.mark.parametrize("correlation", [True, False])
def test_kernel_matches_reference_implementation(matching: str, correlation: bool) -> None:
    cfg = cfg_with(
        "scenario.duration_s=400",
        f"filter.matching={matching}",
        f"filter.rate_noise_correlation={str(correlation).lower()}",
        "scenario.ads.gaps=[{start_s: 120, end_s: 160}]",
    )
    data = simulate(cfg, 21, 2)
    params = FilterParams.from_config(cfg)
    kf = TransferAlignmentKF(params, 2)
    kf.initialize(data.ads_q[:, 0])
    # a different process-noise factor per trial, epoch and calibration term
    kappa = np.random.default_rng(8).uniform(0.01, 100.0, (2, data.n_epochs, 9))
    rec = kf.step_data(data, 0, data.n_epochs, kappa=kappa, record_cov=True)
    assert rec.cov is not None
    for b in range(2):
        est, cov = run_reference(
            params, data.gyro[b], data.ads_q[b], data.ads_rate[b], data.has_meas, kappa[b]
        )
        sigma = np.sqrt(np.einsum("nii->ni", cov))
        # attitude: compare rotations; b̂, p̂: compare in units of the filter's sigma
        d_att = (
            Rotation.from_quat(est[:, 0:4]).inv() * Rotation.from_quat(rec.est[b, :, 0:4])
        ).as_rotvec()
        assert np.max(np.abs(d_att) / sigma[:, 0:3]) < 1e-5
        assert np.max(np.abs(est[:, 4:] - rec.est[b, :, 4:]) / sigma[:, 3:]) < 1e-5
        norm = np.sqrt(sigma[:, :, None] * sigma[:, None, :])
        assert np.max(np.abs(cov - rec.cov[b]) / norm) < 1e-8
    # records are consistent with one another
    np.testing.assert_allclose(rec.var, np.einsum("bnii->bni", rec.cov))
    assert np.isnan(rec.nis_att[:, 120:160]).all()
    assert np.all(rec.loglik[:, 120:160] == 0.0)
    assert np.all(rec.dx[:, 120:160] == 0.0)
    assert np.isfinite(rec.nis_att[:, :120]).all()
    if matching == "attitude":
        assert np.isnan(rec.nis_rate).all()


def test_block_stepping_equals_one_call() -> None:
    cfg = cfg_with("scenario.duration_s=300")
    data = simulate(cfg, 2, 3)
    params = FilterParams.from_config(cfg)
    whole = TransferAlignmentKF(params, 3)
    whole.initialize(data.ads_q[:, 0])
    rec = whole.step_data(data, 0, 300)
    parts = TransferAlignmentKF(params, 3)
    parts.initialize(data.ads_q[:, 0])
    recs = [parts.step_data(data, k, k + 10) for k in range(0, 300, 10)]
    np.testing.assert_array_equal(np.concatenate([r.est for r in recs], axis=1), rec.est)
    np.testing.assert_array_equal(parts.P, whole.P)


def test_kappa_per_trial_and_per_epoch() -> None:
    cfg = cfg_with("scenario.duration_s=1000")
    data = simulate(cfg, 2, 2)
    params = FilterParams.from_config(cfg)
    kf = TransferAlignmentKF(params, 2)
    kf.initialize(data.ads_q[:, 0])
    kap = np.ones((2, 1000))
    kap[1] = 100.0
    rec = kf.step_data(data, 0, 1000, kappa=kap)
    # more process noise on the calibration block → larger calibration variance
    assert np.all(rec.var[1, -1, 6:] > rec.var[0, -1, 6:])
    single = TransferAlignmentKF(params, 1)
    single.initialize(data.ads_q[1:2, 0])
    rec1 = single.step(
        data.gyro[1:2], data.ads_q[1:2], data.ads_rate[1:2], data.has_meas, np.array([100.0])
    )
    np.testing.assert_array_equal(rec1.est[0], rec.est[1])


@pytest.mark.parametrize("bad", [np.nan, 0.0, -1.0, np.inf])
def test_bad_kappa_is_rejected(bad: float) -> None:
    cfg = cfg_with("scenario.duration_s=20")
    data = simulate(cfg, 0, 1)
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 1)
    kf.initialize(data.ads_q[:, 0])
    with pytest.raises(ValueError, match="kappa"):
        kf.step_data(data, 0, 10, kappa=bad)


def test_shape_errors_are_clear() -> None:
    cfg = cfg_with("scenario.duration_s=20")
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 2)
    with pytest.raises(ValueError, match="ads_q0"):
        kf.initialize(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="gyro must have shape"):
        kf.step(np.zeros((1, 5, 3)), np.zeros((2, 5, 4)), np.zeros((2, 5, 3)), np.ones(5, bool))


def test_non_finite_input_flags_divergence_and_freezes_the_trial() -> None:
    cfg = cfg_with("scenario.duration_s=100")
    data = simulate(cfg, 0, 2)
    gyro = data.gyro.copy()
    gyro[0, 40] = np.nan
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 2)
    kf.initialize(data.ads_q[:, 0])
    rec = kf.step(gyro, data.ads_q, data.ads_rate, data.has_meas)
    assert kf.diverged.tolist() == [True, False]
    assert np.isnan(rec.est[0, 41:]).all()
    assert np.isfinite(rec.est[1]).all()
    # the healthy trial is unaffected by its neighbour
    alone = TransferAlignmentKF(FilterParams.from_config(cfg), 1)
    alone.initialize(data.ads_q[1:2, 0])
    rec1 = alone.step(data.gyro[1:2], data.ads_q[1:2], data.ads_rate[1:2], data.has_meas)
    np.testing.assert_array_equal(rec1.est[0], rec.est[1])


def test_loglik_from_the_records() -> None:
    """ℓ = −½ (νᵀS⁻¹ν + log det S) where there was an update, 0 where there was none, −inf where
    an estimate is not finite, from records written by hand."""
    from qkf.transfer_alignment.filter import FilterRecord

    rng = np.random.default_rng(4)
    b, n = 2, 6
    stats = rng.normal(size=(b, n, 5))  # the kernel's layout: column 2 NIS, column 3 log det S
    stats[0, 1, 2] = np.nan  # no measurement
    est = rng.normal(size=(b, n, 16))
    est[1, 4, 9] = np.inf  # diverged
    est[1, 5, 0] = np.nan  # diverged, and no measurement either
    stats[1, 5, 2] = np.nan
    empty = np.empty((b, n, 15))
    rec = FilterRecord(
        est=est, var=empty, cov=None, dx=empty, innov=np.empty((b, n, 6)),
        nis_att=stats[..., 0], nis_rate=stats[..., 1], nis=stats[..., 2],
        logdet_s=stats[..., 3], trace_s_att=stats[..., 4], rate=np.empty((b, n, 3)),
    )  # fmt: skip
    expected = -0.5 * (stats[..., 2] + stats[..., 3])
    expected[0, 1] = 0.0
    expected[1, 4] = expected[1, 5] = -np.inf
    np.testing.assert_array_equal(rec.loglik, expected)
