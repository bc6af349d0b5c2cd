"""The GLR reset method: its CUSUM by hand, the re-opening it adds to the covariance, that it
fires on a calibration jump and not without one, and that without alarms it is the fixed-κ
filter bit for bit (docs/methods.md, "GLR reset")."""

from __future__ import annotations

import math

import numpy as np

from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods.base import new_filter, validate_output
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.methods.fixed import run_fixed
from qkf.transfer_alignment.methods.glr import (
    cusum_step,
    glr_filter,
    log_likelihood_ratio,
    reopen_calibration,
    run_glr,
)
from qkf.transfer_alignment.scenario import simulate


def test_cusum_by_hand() -> None:
    # m = 6 rows, λ = 4: ℓ = ½ (¾ NIS − 6 ln 4) = 0.375 NIS − 4.158883
    nis = np.array([6.0, 30.0, 40.0, 2.0, np.nan, 50.0])
    ell = log_likelihood_ratio(nis, 6, 4.0)
    np.testing.assert_allclose(
        ell, [-1.908883, 7.091117, 10.841117, -3.408883, 0.0, 14.591117], atol=1e-6
    )
    g, trace = np.zeros(1), []
    for value in ell:
        g = cusum_step(g, np.array([value]))
        trace.append(float(g[0]))
    # 0 (clipped), 7.09, 7.09 + 10.84, − 3.41, held (no measurement), + 14.59
    np.testing.assert_allclose(trace, [0.0, 7.091117, 17.932234, 14.523351, 14.523351, 29.114468])
    # the mean drift under no change is negative for any λ > 1: ½ m (1 − 1/λ − ln λ)
    for lam in (1.1, 4.0, 100.0):
        drift = float(log_likelihood_ratio(np.array([3.0]), 3, lam)[0])
        assert drift == 0.5 * 3 * (1 - 1 / lam) - 1.5 * math.log(lam) < 0.0


def test_reopening_adds_exactly_the_stated_variance() -> None:
    cfg = load_config("paper", ["scenario.duration_s=60"])
    data = simulate(cfg, 0, 3)
    kf = new_filter(cfg, data)
    kf.step_data(data, 0, 20)
    before = kf.P.copy()
    reopen_calibration(kf, np.array([False, True, False]), 300e-6)
    after = kf.P
    expected = before[1].copy()
    expected[np.arange(6, 15), np.arange(6, 15)] += (300e-6) ** 2  # (reset_ppm · 1e-6)²
    np.testing.assert_allclose(after[1], expected, rtol=1e-13, atol=0.0)
    np.testing.assert_array_equal(after[[0, 2]], before[[0, 2]])  # other trials untouched
    np.testing.assert_allclose(after[1], after[1].T, rtol=1e-15, atol=0.0)
    assert np.linalg.eigvalsh(after[1]).min() > 0.0


def test_resets_after_the_jump_and_not_without_one() -> None:
    """thermal_snap: misalignments jump by 200 µrad at 1800 s, as a rotation starts; paper has
    no change (64 trials of seed 77 at the default h = 15: no alarm, largest g 11.7)."""
    snap = load_config("thermal_snap", ["scenario.duration_s=2100"])
    data = simulate(snap, 5, 3)
    out = validate_output(
        run_glr(snap, data), "glr", 3, data.n_epochs, covariance_epochs(snap).size
    )
    for row in range(3):
        times = data.t[out.logs["reopen"][row]]
        assert times.size == 1 and 1800.0 <= times[0] <= 1810.0
    assert out.cov is not None and np.isfinite(out.cov).all()
    paper = load_config("paper")
    quiet = run_glr(paper, simulate(paper, 5, 3))
    assert not quiet.logs["alarm"].any()
    assert quiet.logs["cusum"].max() < paper.adaptive.glr.threshold


def test_quiet_time_keeps_alarms_from_reopening() -> None:
    """A low threshold alarms repeatedly after the jump; within quiet_s only the first one
    re-opens."""
    sets = ["scenario.duration_s=2400", "adaptive.glr.threshold=3"]
    cfg = load_config("thermal_snap", [*sets, "adaptive.glr.quiet_s=1e6"])
    data = simulate(cfg, 5, 2)
    out = run_glr(cfg, data)
    assert (out.logs["alarm"].sum(axis=1) > 1).all()
    assert (out.logs["reopen"].sum(axis=1) == 1).all()
    eager = run_glr(load_config("thermal_snap", [*sets, "adaptive.glr.quiet_s=0"]), data)
    np.testing.assert_array_equal(eager.logs["reopen"], eager.logs["alarm"])


def test_without_alarms_it_is_the_fixed_filter_bit_for_bit() -> None:
    kappa = 10.0**0.4
    cfg = load_config(
        "thermal_snap",
        ["scenario.duration_s=1900", "adaptive.glr.threshold=1e300", f"adaptive.glr.kappa={kappa}"],
    )
    data = simulate(cfg, 2, 2)
    out, ref = run_glr(cfg, data), run_fixed(cfg, data, kappa)
    assert not out.logs["alarm"].any()
    np.testing.assert_array_equal(out.est, ref.est)
    np.testing.assert_array_equal(out.cov, ref.cov)
    np.testing.assert_array_equal(out.diverged, ref.diverged)
    assert out.kappa is not None and np.all(out.kappa == kappa)


def test_speculative_blocks_equal_stepping_one_epoch_at_a_time() -> None:
    """Re-openings inside a block roll the filter back: the result is that of deciding after
    every single epoch (here several re-openings per trial, at different epochs per trial)."""
    cfg = load_config(
        "thermal_snap",
        [
            "scenario.duration_s=2000",
            "adaptive.glr.threshold=3",
            "adaptive.glr.quiet_s=20",
            "adaptive.glr.inflation=4",
        ],
    )
    data = simulate(cfg, 1, 2)
    fast = glr_filter(cfg, data, cfg.adaptive.glr, block=64)
    slow = glr_filter(cfg, data, cfg.adaptive.glr, block=1)
    assert (fast.logs["reopen"].sum(axis=1) > 2).all()
    for key in ("cusum", "alarm", "reopen"):
        np.testing.assert_array_equal(fast.logs[key], slow.logs[key])
    np.testing.assert_array_equal(fast.est, slow.est)
    np.testing.assert_array_equal(fast.cov, slow.cov)
