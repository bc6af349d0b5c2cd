"""The adaptive methods on small cases worked by hand, and their safeguards."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.core import kalman
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.methods import METHODS
from qkf.transfer_alignment.methods.fixed import tuned_kappa
from qkf.transfer_alignment.methods.qlearning import greedy_switch, q_update, run_qkf
from qkf.transfer_alignment.methods.sage_husa import (
    forgetting_weights,
    run_sage_husa,
    sage_husa_step,
)
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with
from tests.mmae_numpy import combine, update_log_weights


def test_sage_husa_forgetting_weights() -> None:
    d = forgetting_weights(0.97, 200)
    assert d[0] == 1.0
    assert d[1] == pytest.approx(0.03 / (1 - 0.97**2))
    assert d[2] == pytest.approx(0.03 / (1 - 0.97**3))
    assert d[-1] == pytest.approx(0.03, rel=0.01)
    assert np.all(np.diff(d) < 0)


def test_sage_husa_on_a_scalar_random_walk_by_hand() -> None:
    """x_{k+1} = x_k + w, z_k = x_k + v: three steps of KF + Sage-Husa, against the formulas."""
    r, b = 0.5, 0.9
    z = [1.0, 0.2, -0.4]
    q_min, q_max = 1e-6, 10.0
    d = forgetting_weights(b, 3)
    # library
    x = np.zeros((1, 1))
    p = np.ones((1, 1, 1))
    q_hat = np.array([0.1])
    var_prev = np.array([1.0])
    lib = []
    for k in range(3):
        x_before = x[0, 0]
        kalman.update(x, p, np.array([[z[k]]]), np.eye(1), np.array([[r]]))
        corr = x[0, 0] - x_before
        q_hat = sage_husa_step(q_hat, d[k], np.array([corr]), p[:, 0, 0], var_prev, q_min, q_max)
        lib.append(q_hat[0])
        var_prev = p[:, 0, 0].copy()
        kalman.predict(x, p, np.eye(1), q_hat[None, :, None])
    # by hand
    xh, ph, qh, vprev = 0.0, 1.0, 0.1, 1.0
    hand = []
    for k in range(3):
        s = ph + r
        gain = ph / s
        nu = z[k] - xh
        xh += gain * nu
        ph = (1 - gain) ** 2 * ph + gain**2 * r  # Joseph
        obs = (gain * nu) ** 2 + ph - vprev
        qh = min(max((1 - d[k]) * qh + d[k] * obs, q_min), q_max)
        hand.append(qh)
        vprev = ph
        ph += qh
    np.testing.assert_allclose(lib, hand, rtol=1e-12)


def test_sage_husa_step_clips() -> None:
    out = sage_husa_step(
        np.array([2.0]), 0.5, np.array([1.0]), np.array([3.0]), np.array([2.5]), 0, 1.6
    )
    assert out[0] == 1.6  # unclipped: 0.5 * 2 + 0.5 * (1 + 3 - 2.5) = 1.75
    out = sage_husa_step(
        np.array([2.0]), 0.5, np.array([0.0]), np.array([1.0]), np.array([9.0]), 0.3, 5
    )
    assert out[0] == 0.3  # negative raw estimate


def test_q_learning_update_and_switch_by_hand() -> None:
    table = np.zeros((1, 11, 11))
    q_update(table, np.array([5]), np.array([7]), np.array([2.0]), alpha=0.1, gamma=0.9)
    assert table[0, 5, 7] == pytest.approx(0.2)
    q_update(table, np.array([7]), np.array([5]), np.array([-1.0]), alpha=0.1, gamma=0.9)
    # target = −1 + 0.9 · max_a' Q(5, a') = −1 + 0.18
    assert table[0, 7, 5] == pytest.approx(0.1 * (-1 + 0.9 * 0.2))
    assert greedy_switch(table, np.array([5]))[0] == 7  # best value 0.2 > 0: switch
    assert greedy_switch(table, np.array([7]))[0] == 7  # best value 0: stay
    assert np.count_nonzero(table) == 2


def test_qkf_first_period_by_hand() -> None:
    """Rebuild the first decision period with plain filters and check the learned value."""
    cfg = cfg_with("scenario.duration_s=60", "adaptive.qkf.period_s=10")
    data = simulate(cfg, 3, 2)
    out = run_qkf(cfg, data)
    kappas = np.asarray(cfg.adaptive.actions.values())
    s0 = 5
    assert kappas[s0] == pytest.approx(1.0)
    assert np.all(out.logs["kappa_index"][:, 0] == s0)
    a0 = out.logs["action"][:, 0]
    params = FilterParams.from_config(cfg)
    main = TransferAlignmentKF(params, 2)
    main.initialize(data.ads_q[:, 0])
    explore = main.copy()
    rec_m = main.step_data(data, 0, 10, kappa=kappas[s0])
    ll_m = rec_m.loglik.sum(axis=1)
    ll_e = explore.step_data(data, 0, 10, kappa=kappas[a0]).loglik.sum(axis=1)
    r = (ll_e - ll_m) / 10.0
    np.testing.assert_allclose(out.logs["reward"][:, 0], r, rtol=1e-12)
    np.testing.assert_array_equal(out.est[:, :10], rec_m.est)  # the output is the main filter
    # Q(s0, a0) after the first update is α r (the table started at zero) unless a0 came back
    table = np.zeros((2, 11, 11))
    q_update(table, np.full(2, s0), a0, r, 0.1, 0.9)
    for i in range(2):
        assert table[i, s0, a0[i]] == pytest.approx(0.1 * r[i])
    # reproducible per trial: trial 1 alone gives the same choices
    alone = run_qkf(cfg, simulate(cfg, 3, [1]))
    np.testing.assert_array_equal(alone.logs["action"][0], out.logs["action"][1])
    np.testing.assert_array_equal(alone.est[0], out.est[1])


def test_mmae_weights_two_models() -> None:
    lw = np.log(np.array([[0.5, 0.5]]))
    w = np.exp(update_log_weights(lw, np.array([[0.0, np.log(3.0)]]), floor=0.0))
    np.testing.assert_allclose(w, [[0.25, 0.75]])
    w = np.exp(update_log_weights(lw, np.array([[0.0, np.log(1e9)]]), floor=0.3))
    np.testing.assert_allclose(w, [[0.3 / 1.3, 1.0 / 1.3]], rtol=1e-6)
    # a model whose likelihood is −inf (diverged) is out for good, floor or not
    w = np.exp(update_log_weights(lw, np.array([[-np.inf, 0.0]]), floor=0.3))
    np.testing.assert_allclose(w, [[0.0, 1.0]])


def test_mmae_combination_of_two_models() -> None:
    est = np.zeros((1, 2, 1, 16))
    q1 = Rotation.from_rotvec([0.1, 0.0, 0.0])
    q2 = q1 * Rotation.from_rotvec([0.0, 0.002, 0.0])
    est[0, 0, 0, 0:4] = q1.as_quat()
    est[0, 1, 0, 0:4] = q2.as_quat()
    est[0, 0, 0, 4:] = 1.0
    est[0, 1, 0, 4:] = 3.0
    w = np.array([[[0.25], [0.75]]])
    out = combine(est, w)
    np.testing.assert_allclose(out[0, 0, 4:], 2.5)
    rel = (q2.inv() * Rotation.from_quat(out[0, 0, 0:4])).as_rotvec()
    np.testing.assert_allclose(rel, [0.0, -0.25 * 0.002, 0.0], atol=1e-12)


@pytest.mark.slow  # a fixed KF per κ of the action set, twice
def test_tuned_kappa_is_the_best_on_its_own_seeds() -> None:
    cfg = cfg_with("scenario.duration_s=400", "adaptive.tuned.trials=3")
    kappa, scores = tuned_kappa(cfg)
    assert kappa in cfg.adaptive.actions.values()
    assert scores[cfg.adaptive.actions.values().index(kappa)] == min(scores)
    assert cfg.adaptive.tuned.seed != cfg.run.seed
    out = METHODS["kf-tuned"](cfg, simulate(cfg, 0, 2))
    assert "κ =" in out.notes["kf-tuned"]


@pytest.mark.slow
@pytest.mark.parametrize(
    "preset", ["paper", "attitude_only", "thermal_drift", "thermal_snap", "noise_mismatch"]
)
def test_sage_husa_q_stays_finite_and_positive(preset: str) -> None:
    cfg = cfg_with(base=f"{preset}.yaml")
    data = simulate(cfg, 17, 20)
    out = run_sage_husa(cfg, data)
    kappa = out.logs["kappa_terms"]  # (B, N, 9): the adapted diagonal Q̂ / (q_p0 Δt)
    assert np.all(np.isfinite(kappa))
    lo, hi = min(cfg.adaptive.actions.values()), max(cfg.adaptive.actions.values())
    assert np.all(kappa >= lo * (1 - 1e-12)) and np.all(kappa <= hi * (1 + 1e-12))
    assert not out.diverged.any()
    assert np.all(np.isfinite(out.est))


def test_attitude_noise_adaptation_step_by_hand() -> None:
    from qkf.transfer_alignment.methods.sage_husa import adapt_attitude_noise

    nu = np.array([[1.0, 2.0, 2.0]])  # |ν|² = 9
    trace_s = np.array([3.0 * 0.5 + 6.0])  # H P Hᵀ has trace 6, R = 0.5 I
    out = adapt_attitude_noise(np.array([0.5]), 0.25, nu, trace_s, r_min=0.01)
    assert out[0] == pytest.approx(0.75 * 0.5 + 0.25 * (9.0 - 6.0) / 3.0)
    assert adapt_attitude_noise(np.array([0.5]), 1.0, nu, np.array([40.0]), r_min=0.2)[0] == 0.2
    assert adapt_attitude_noise(np.array([0.5]), 1.0, nu * np.nan, trace_s, 0.01)[0] == 0.5


@pytest.mark.slow
@pytest.mark.parametrize("true_arcsec", [1.0, 10.0])
def test_sage_husa_learns_the_true_attitude_noise(true_arcsec: float) -> None:
    from qkf.core import units

    cfg = cfg_with(
        f"scenario.ads.attitude_sigma_arcsec={true_arcsec}",
        "filter.attitude_sigma_arcsec=3",
        "adaptive.sage_husa.adapt_r=true",
        "scenario.duration_s=1200",
    )
    out = run_sage_husa(cfg, simulate(cfg, 4, 8))
    learned = out.logs["sigma_a"][:, -300:].mean() / units.ARCSEC
    assert learned == pytest.approx(true_arcsec, rel=0.15)


def test_qkf_switch_options_by_hand() -> None:
    from qkf.transfer_alignment.methods.qlearning import greedy_switch, normalize_reward

    table = np.zeros((3, 3, 3))
    table[0, 1] = [0.2, 0.1, 0.3]  # trial 0 in state 1: best 2 (0.3), Q(s, s) = 0.1
    table[1, 0] = [0.05, 0.0, 0.04]  # trial 1 in state 0: best is staying (0.05)
    table[2, 2] = [0.0, 0.01, 0.0]  # trial 2 in state 2: best 1 (0.01)
    s = np.array([1, 0, 2])
    np.testing.assert_array_equal(greedy_switch(table, s), [2, 0, 1])  # the paper's rule
    np.testing.assert_array_equal(greedy_switch(table, s, threshold=0.05), [2, 0, 2])
    np.testing.assert_array_equal(greedy_switch(table, s, hysteresis=0.15), [2, 0, 2])
    np.testing.assert_array_equal(greedy_switch(table, s, hysteresis=0.25), [1, 0, 2])
    sq = np.zeros(2)
    r1 = normalize_reward(np.array([2.0, 0.0]), sq, 1)  # RMS of [2] is 2
    np.testing.assert_allclose(r1, [1.0, 0.0])
    r2 = normalize_reward(np.array([-4.0, 3.0]), sq, 2)  # RMS of [2, -4] = √10; of [0, 3] = √4.5
    np.testing.assert_allclose(r2, [-4.0 / np.sqrt(10.0), 3.0 / np.sqrt(4.5)])


def test_qkf_hysteresis_switches_less() -> None:
    cfg = cfg_with("scenario.duration_s=600")
    data = simulate(cfg, 1, 3)
    plain = METHODS["qkf"](cfg, data)
    held = METHODS["qkf"](
        cfg_with(
            "scenario.duration_s=600",
            "adaptive.qkf.reward_normalization=running_rms",
            "adaptive.qkf.hysteresis=0.5",
        ),
        data,
    )
    switches = [
        int(np.count_nonzero(np.diff(o.logs["kappa_index"], axis=1))) for o in (plain, held)
    ]
    assert switches[1] < switches[0]
