"""Numerical robustness: P stays symmetric positive definite over 10⁶ steps while κ jumps
between the ends of the action set (0.01 and 100) at random."""

from __future__ import annotations

import numpy as np
import pytest

from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with

STEPS = 1_000_000
BLOCK = 20_000


def _long_config():  # type: ignore[no-untyped-def]
    # x, y, z rotations at 1 deg/s repeated every 2000 s, for 10⁶ s
    period = 2000
    man = ", ".join(
        f"{{start_s: {t0 + 100 * i}, duration_s: 100, axis: {ax}, rate_deg_s: 1.0}}"
        for t0 in range(0, STEPS, period)
        for i, ax in enumerate("xyz")
    )
    return cfg_with(f"scenario.duration_s={STEPS}", f"scenario.maneuvers=[{man}]")


@pytest.mark.slow
@pytest.mark.parametrize("matching", ["attitude_rate"])
def test_covariance_stays_spd_over_a_million_steps(matching: str) -> None:
    cfg = _long_config()
    data = simulate(cfg, 9, 1)
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 1)
    kf.initialize(data.ads_q[:, 0])
    rng = np.random.default_rng(0)
    kappa = np.where(rng.random((1, STEPS)) < 0.5, 0.01, 100.0)
    for k0 in range(0, STEPS, BLOCK):
        rec = kf.step_data(data, k0, k0 + BLOCK, kappa=kappa[:, k0 : k0 + BLOCK], record_cov=True)
        assert not kf.diverged.any(), f"diverged before epoch {k0 + BLOCK}"
        cov = rec.cov[0]
        assert np.all(np.isfinite(cov))
        assert np.array_equal(cov, np.swapaxes(cov, 1, 2)), "P not exactly symmetric"
        # scale-free positive definiteness: every eigenvalue of the correlation matrix above
        # 1e-12, i.e. corr − 1e-12·I has a Cholesky factor (a quarter of eigvalsh's time)
        sd = np.sqrt(np.einsum("nii->ni", cov))
        corr = cov / (sd[:, :, None] * sd[:, None, :])
        try:
            np.linalg.cholesky(corr - 1e-12 * np.eye(corr.shape[-1]))
        except np.linalg.LinAlgError:
            pytest.fail(f"P lost positive definiteness (eigenvalue <= 1e-12) in block {k0}")
