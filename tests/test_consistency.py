"""Statistical checks over Monte Carlo trials (navlie-style): with the truth drawn from the
filter's prior and the filter's q_p equal to the truth's, the filter must be consistent (NEES)
and efficient (RMS at the CRLB)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from qkf.core.stats import nees as nees_fn
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.metrics import state_errors
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with

MATCHING = ["attitude", "attitude_rate"]


def _matched(matching: str):  # type: ignore[no-untyped-def]
    # the truth is constant; the filter's q_p is the CRLB's floor for a constant truth
    return cfg_with(
        "scenario.randomize_truth=true", "filter.qp0=1e-20", f"filter.matching={matching}"
    )


def _run(cfg, trials: int, seed: int, record_cov: bool):  # type: ignore[no-untyped-def]
    data = simulate(cfg, seed, trials)
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), trials)
    kf.initialize(data.ads_q[:, 0])
    rec = kf.step_data(data, 0, data.n_epochs, record_cov=record_cov)
    assert not kf.diverged.any()
    return data, rec, state_errors(rec.est, data.q_true, data.bias, data.calib)


@pytest.mark.slow
@pytest.mark.parametrize("matching", MATCHING)
def test_nees_inside_chi_square_band(matching: str) -> None:
    trials = 60
    cfg = _matched(matching)
    data, rec, err = _run(cfg, trials, seed=101, record_cov=True)
    avg_nees = nees_fn(err, rec.cov).mean(axis=0)
    lo, hi = stats.chi2.ppf([0.005, 0.995], 15 * trials) / trials
    late = data.t >= 400.0
    inside = (avg_nees[late] >= lo) & (avg_nees[late] <= hi)
    assert inside.mean() >= 0.95, f"{inside.mean():.3f} of epochs inside [{lo:.2f}, {hi:.2f}]"


@pytest.mark.slow
def test_without_the_noise_correlation_rate_matching_is_overconfident() -> None:
    """Why the filter models the gyro noise shared by z_r and the attitude propagation: without
    it the same noise is counted twice and the bias NEES is far above its dimension."""
    trials = 60
    cfg = cfg_with(
        "scenario.randomize_truth=true", "filter.qp0=1e-20", "filter.rate_noise_correlation=false"
    )
    data, rec, err = _run(cfg, trials, seed=101, record_cov=True)
    late = data.t >= 400.0
    bias_nees = nees_fn(err[:, late, 3:6], rec.cov[:, late, 3:6, 3:6]).mean()
    hi = stats.chi2.ppf(0.995, 3 * trials * late.sum()) / (trials * late.sum())
    assert bias_nees > hi


@pytest.mark.slow
@pytest.mark.parametrize("matching", MATCHING)
def test_rms_at_last_epoch_is_at_the_crlb(matching: str) -> None:
    trials = 240
    cfg = _matched(matching)
    _, _, err = _run(cfg, trials, seed=202, record_cov=False)
    rms = np.sqrt(np.mean(err[:, -1] ** 2, axis=0))
    bound = crlb(cfg).bound[-1]
    ratio = rms / bound
    assert np.all((ratio > 0.8) & (ratio < 1.25)), np.round(ratio, 3)
