"""The covariance methods report, and how the benchmark judges it by NEES (docs/methods.md,
"Consistency")."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.transfer_alignment.benchmark import nees_summary, run_benchmark
from qkf.transfer_alignment.methods import MethodOutput, NamedMethod
from qkf.transfer_alignment.methods.base import new_filter
from qkf.transfer_alignment.methods.covariance import (
    CovarianceRecorder,
    covariance_epochs,
    step_recording,
)
from qkf.transfer_alignment.methods.fixed import run_kf
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with
from tests.mmae_numpy import mixture_covariance

SHORT = ("scenario.duration_s=240", "run.settled_s=120", "run.nees_every_s=5")


def test_step_recording_changes_nothing_and_records_the_posterior_covariance() -> None:
    cfg = cfg_with(*SHORT)
    data = simulate(cfg, 4, 3)
    kappa = np.linspace(0.5, 3.0, data.n_trials * data.n_epochs).reshape(data.n_trials, -1)
    plain = new_filter(cfg, data)
    ref = plain.step_data(data, 0, data.n_epochs, kappa=kappa, record_cov=True)
    kf = new_filter(cfg, data)
    rec = CovarianceRecorder(cfg, data.n_trials)
    out = step_recording(kf, data, 0, data.n_epochs, kappa, rec)
    np.testing.assert_array_equal(out.est, ref.est)
    np.testing.assert_array_equal(out.nis, ref.nis)
    assert ref.cov is not None
    np.testing.assert_array_equal(rec.cov, ref.cov[:, rec.epochs])
    np.testing.assert_array_equal(kf.P, plain.P)


def test_covariance_epochs_follow_the_config() -> None:
    cfg = cfg_with(*SHORT)
    k = covariance_epochs(cfg)
    t = k * cfg.scenario.dt_s
    np.testing.assert_allclose(np.diff(t), 5.0)
    assert t[0] == pytest.approx(5.0) and t[-1] < cfg.scenario.duration_s


def test_mixture_covariance_by_hand() -> None:
    # two members; member 1 is rotated 1e-3 rad about z and has b_x larger by 2e-6
    p1, p2 = np.eye(15) * 1e-6, np.eye(15) * 4e-6
    e1 = np.zeros(16)
    e1[3] = 1.0
    e2 = e1.copy()
    e2[0:4] = Rotation.from_rotvec([0.0, 0.0, 1e-3]).as_quat()
    e2[4] += 2e-6
    w = np.array([[0.25, 0.75]])
    mix = e1.copy()  # combined about member 0
    got = mixture_covariance(np.stack([e1, e2])[None], np.stack([p1, p2])[None], w, mix[None])[0]
    d2 = np.zeros(15)
    d2[2], d2[3] = 1e-3, 2e-6
    want = 0.25 * p1 + 0.75 * (p2 + np.outer(d2, d2))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-18)


def test_nees_summary_band_by_hand() -> None:
    t = np.array([0.0, 10.0, 20.0, 30.0])
    count = np.array([10, 10, 10, 0])
    avg = np.array([100.0, 15.0, 40.0, np.nan])  # epoch 0 outside the window, 3 has no trials
    s = nees_summary(avg, count, t, 10.0, 0.95)
    # inside [χ²(150)_2.5% /10, χ²(150)_97.5% /10] = [11.7, 18.6]: 15 yes, 40 no
    assert s["nees_in_band"] == pytest.approx(0.5)
    assert s["nees_mean"] == pytest.approx((15.0 + 40.0) / 2 / 15.0)
    assert np.isnan(nees_summary(None, count, t, 10.0, 0.95)["nees_mean"])


def _overconfident(cfg, data):  # type: ignore[no-untyped-def]
    out = run_kf(cfg, data)
    assert out.cov is not None
    return MethodOutput(est=out.est, diverged=out.diverged, cov=out.cov / 4.0)


@pytest.mark.slow
def test_benchmark_nees_passes_the_matched_kf_and_fails_an_overconfident_one() -> None:
    """With the truth drawn from the prior and q_p matching it, the KF's own covariance is
    consistent; the same estimates with the covariance divided by 4 are not (NEES ≈ 4)."""
    cfg = cfg_with(
        *SHORT, "scenario.randomize_truth=true", "filter.qp0=1e-20", "filter.matching=attitude"
    )
    res = run_benchmark(
        cfg, ["kf", NamedMethod("over", _overconfident)], trials=40, seed=7, progress=False
    )
    kf, over = res.methods
    assert 0.85 < kf.summary["nees_mean"] < 1.15, kf.summary
    assert kf.summary["nees_in_band"] >= 0.8, kf.summary
    assert over.summary["nees_mean"] == pytest.approx(4 * kf.summary["nees_mean"], rel=1e-6)
    assert over.summary["nees_in_band"] == 0.0
