"""The variational-Bayes noise scales of the gyro UKF (``qkf.redundant_gyros.vb_noise``): the
process statistic is the smoothed process noise found by conditioning a joint Gaussian, the
measurement terms are the filter's model, the R scale lands within its sampling error of the
truth, the rule follows its equations stepped with filterpy's UKF, a rule that never adapts is
the constant κ, and the tuned rule is never worse than the best constant on its tuning
episodes (docs/redundant_gyros.md, "VB noise scales")."""

from __future__ import annotations

import numpy as np
import pytest

from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros import nis_adaptive as na
from qkf.redundant_gyros import vb_noise as vb
from qkf.redundant_gyros.ukf import CalibrationUKF, measurement, measurement_variance
from tests import vb_noise_numpy as vb_numpy
from tests.gyro_rules import (
    assert_constant_kappa,
    assert_follows_by_hand,
    assert_tuning_nests_the_constants,
)

FAMILY = "gyro_noise_levels"
SHORT = ["scenario.duration_s=160"]  # judged from 100 s (hindsight.SETTLED_S)
SEEDS = [5_000_010, 5_000_011]


def _conditioned_process_noise(
    p: np.ndarray, q: np.ndarray, h: np.ndarray, r: float, z: float, m: np.ndarray
) -> np.ndarray:
    """``E[w wᵀ | z]`` for ``x_{k−1} ~ N(m, p)``, ``w ~ N(0, diag(q))`` independent and
    ``z = h (x_{k−1} + w) + v``, ``v ~ N(0, r)``: the Gaussian conditioning of the joint
    ``[x_{k−1}; w]`` written out, with no filter in it."""
    cov = np.zeros((8, 8))
    cov[:4, :4], cov[4:, 4:] = p, np.diag(q)
    row = np.concatenate([h, h])  # z = row · [x_{k−1}; w] + v
    mean = np.concatenate([m, np.zeros(4)])
    s = row @ cov @ row + r
    gain = cov @ row / s
    post_mean = mean + gain * (z - row @ mean)
    post_cov = cov - np.outer(gain, gain) * s
    w_mean = post_mean[4:]
    return np.asarray(post_cov[4:, 4:] + np.outer(w_mean, w_mean))


@pytest.mark.parametrize("theta_r", [1.0, 2.3])
def test_process_statistic_is_the_smoothed_process_noise(theta_r: float) -> None:
    """Linear random-walk Kalman filters with a scalar measurement: ``s_Q`` equals the trace of
    ``E[w wᵀ | z_{1:k}] / Q₀`` found by conditioning the joint of the previous state and the
    process noise on the reading, with every covariance in the truth's scale ``θ_R`` (the
    filter's own, θ_R = 1, run unscaled: the means and gains do not change)."""
    rng = np.random.default_rng(5)
    n, period = 2, 6
    q2 = rng.uniform(0.5, 2.0, 4)
    kappa = rng.uniform(0.1, 10.0, n)
    dt = rng.uniform(0.05, 0.2, (n, period))
    r = rng.uniform(0.1, 1.0, n)
    a = rng.normal(size=(n, 4, 4))
    p = a @ np.swapaxes(a, 1, 2) + 0.5 * np.eye(4)
    x = rng.normal(size=(n, 4))
    x_prev, p_prev = x.copy(), p.copy()
    est, cov = np.empty((n, period, 4)), np.empty((n, period, 4, 4))
    expected = np.empty((n, period))
    for e in range(n):
        xe, pe = x[e], p[e]
        for k in range(period):
            q = kappa[e] * q2 * dt[e, k]
            h = rng.normal(size=4)
            z = float(h @ xe + rng.normal() * 3.0)
            cond = _conditioned_process_noise(theta_r * pe, theta_r * q, h, theta_r * r[e], z, xe)
            expected[e, k] = float(np.sum(np.diag(cond) / (q2 * dt[e, k])))
            p_minus = pe + np.diag(q)
            s = h @ p_minus @ h + r[e]
            gain = p_minus @ h / s
            xe = xe + gain * (z - h @ xe)
            pe = p_minus - np.outer(gain, gain) * s
            est[e, k], cov[e, k] = xe, pe
    q_step = q2[None, None, :] * dt[:, :, None]
    theta = np.full(n, theta_r)
    got = vb.process_statistic(est, cov, x_prev, p_prev, q_step, kappa, theta)
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    # epochs not run (NaN) have no statistic
    est[1, 3:], cov[1, 3:] = np.nan, np.nan
    got = vb.process_statistic(est, cov, x_prev, p_prev, q_step, kappa, theta)
    np.testing.assert_allclose(got[1, :3], expected[1, :3], rtol=1e-9)
    assert np.isnan(got[1, 3:]).all()


def test_measurement_terms_are_the_filters_model() -> None:
    """The numpy reference's ``h``, ``R₀`` against the filter's own functions, ``H`` against
    central differences (exact up to rounding: ``h`` is linear in each coordinate)."""
    cfg = load_config(FAMILY, SHORT)
    ep = hs.episode(cfg, SEEDS[0])
    s = ep.setup
    rng = np.random.default_rng(3)
    x = s.x0 + rng.normal(size=(5, 4)) * s.p0_sd
    rate = ep.inputs.rate[rng.integers(0, ep.n_epochs, 5)]
    h, jac, r0 = vb_numpy.measurement_terms(s, x, rate)
    for i in range(5):
        assert h[i] == pytest.approx(measurement(x[i], rate[i], s)[0], rel=1e-12, abs=1e-15)
        assert r0[i] == pytest.approx(measurement_variance(s, x[i]), rel=1e-12)
        for j in range(4):
            step = np.zeros(4)
            step[j] = 1e-3 * s.p0_sd[j]
            fd = measurement(x[i] + step, rate[i], s) - measurement(x[i] - step, rate[i], s)
            assert jac[i, j] == pytest.approx(fd[0] / (2 * step[j]), rel=1e-6, abs=1e-12)


def test_compiled_measurement_statistic_equals_the_numpy_reference() -> None:
    """Random states and covariances around the prior, epochs not run (NaN) at the end of one
    row and a whole row not run: the compiled statistic equals the numpy one to 1e-12."""
    cfg = load_config(FAMILY, SHORT)
    ep = hs.episode(cfg, SEEDS[0])
    s = ep.setup
    rng = np.random.default_rng(8)
    n, period = 3, 7
    est = s.x0 + rng.normal(size=(n, period, 4)) * s.p0_sd
    a = rng.normal(size=(n, period, 4, 4)) * s.p0_sd
    cov = a @ np.swapaxes(a, -1, -2)
    x_prev = s.x0 + rng.normal(size=(n, 4)) * s.p0_sd
    theta = rng.uniform(0.5, 3.0, n)
    z = rng.normal(size=(n, period)) * 0.01
    rate = ep.inputs.rate[rng.integers(0, ep.n_epochs, (n, period))]
    est[1, 4:], cov[1, 4:], est[2], cov[2] = np.nan, np.nan, np.nan, np.nan
    got = vb.measurement_statistic(s, est, cov, x_prev, theta, z, rate)
    want = vb_numpy.measurement_statistic(s, est, cov, x_prev, theta, z, rate)
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert np.isnan(got[1, 4:]).all() and np.isnan(got[2]).all() and np.isfinite(got[0]).all()


@pytest.mark.parametrize("noise_factor", [1.0, 2.0])
def test_the_r_scale_lands_within_its_sampling_error_of_the_truth(noise_factor: float) -> None:
    """With the calibrated gyro's white noise ``f`` × the assumed (no drift change), the R
    scale estimated over whole episodes (600 s) without forgetting is the truth's
    ``(f² σ_j² + T) / (σ_j² + T)`` (``T`` the triad's share of ``R₀``) within four standard
    errors over eight episodes, and the filter is not told ``f``."""
    cfg = load_config(
        FAMILY,
        [
            "scenario.onset.drift_scale=[1,1]",
            f"scenario.onset.noise_factor=[{noise_factor},{noise_factor}]",
        ],
    )
    episodes = [hs.episode(cfg, s) for s in range(5_000_020, 5_000_028)]
    batch = na.EpisodeBatch.of_episodes(cfg, episodes, keep_cov=True)
    _, _, theta_r = vb.run_rule_traced(batch, vb.VbRule("r", float("inf"), 1.0))
    s = episodes[0].setup
    r0 = measurement_variance(s, s.x0)
    triad = r0 - s.noise**2
    truth = (noise_factor**2 * s.noise**2 + triad) / r0
    final = theta_r[:, -1]
    band = 4.0 * float(np.std(final, ddof=1)) / np.sqrt(final.size)
    assert abs(float(np.mean(final)) - truth) < band, (final, truth)
    assert band < 0.05 * truth  # the band is tight enough to mean something


def _by_hand(cfg, seed: int, rule: vb.VbRule) -> float:  # type: ignore[no-untyped-def]
    """The rule stepped with filterpy's UKF, epoch by epoch, from the module's equations."""
    ep = hs.episode(cfg, seed)
    i, s = ep.inputs, ep.setup
    kappas = np.asarray(cfg.environment.actions.values())
    q2 = np.asarray(s.q_sd, dtype=float) ** 2
    ukf = CalibrationUKF(s, float(i.dt[0]))
    per = float(ep.period)
    a_q, b_q, a_r, b_r = 2 * per, 2 * per * rule.kappa0, per / 2, per / 2
    rho = 2.0 ** (-1.0 / rule.halflife)
    kappa, theta_q, theta_r, total = rule.kappa0, rule.kappa0, 1.0, 0.0
    for k0 in range(0, ep.n_epochs, ep.period):
        sum_q = sum_r = 0.0
        epochs = range(k0, min(k0 + ep.period, ep.n_epochs))
        for k in epochs:
            x_before, p_before = ukf.x.copy(), ukf.P.copy()
            res = ukf.step(float(i.z[k]), i.rate[k], float(i.dt[k]), kappa)
            assert res.ok
            q = np.diag(kappa * q2 * float(i.dt[k]))
            g = q @ np.linalg.inv(p_before + q)
            dx = ukf.x - x_before
            e_ww = theta_r * (q - g @ q + g @ ukf.P @ g.T) + np.outer(g @ dx, g @ dx)
            sum_q += float(np.sum(np.diag(e_ww) / (q2 * float(i.dt[k]))))
            h_row = np.empty(4)
            for j in range(4):
                step = np.zeros(4)
                step[j] = 1e-3 * s.p0_sd[j]
                up = measurement(ukf.x + step, i.rate[k], s)[0]
                down = measurement(ukf.x - step, i.rate[k], s)[0]
                h_row[j] = (up - down) / (2 * step[j])
            resid = float(i.z[k]) - measurement(ukf.x, i.rate[k], s)[0]
            hph = float(h_row @ ukf.P @ h_row)
            sum_r += (resid**2 + theta_r * hph) / measurement_variance(s, x_before)
            if k >= ep.settled_from:
                total += float(np.sum(((ukf.x - i.truth[k]) / s.p0_sd) ** 2))
        if "q" in rule.adapt:
            a_q, b_q = rho * a_q + 2 * len(epochs), rho * b_q + 0.5 * sum_q
            theta_q = b_q / a_q
        if "r" in rule.adapt:
            a_r, b_r = rho * a_r + 0.5 * len(epochs), rho * b_r + 0.5 * sum_r
            theta_r = b_r / a_r
        kappa = float(np.clip(theta_q / theta_r, kappas.min(), kappas.max()))
    return total / ((ep.n_epochs - ep.settled_from) * 4)


@pytest.mark.parametrize(
    "rule", [vb.VbRule("qr", 3.0, 1.0), vb.VbRule("r", float("inf"), 15.848931924611142)], ids=str
)
def test_rule_follows_its_equations(rule: vb.VbRule) -> None:
    cfg = load_config(FAMILY, SHORT)
    batch = na.EpisodeBatch.of(cfg, SEEDS, keep_cov=True)
    assert_follows_by_hand(SEEDS, vb.run_rule_on(batch, rule), lambda s: _by_hand(cfg, s, rule))


def test_a_rule_that_never_adapts_is_the_constant_kappa() -> None:
    cfg = load_config(FAMILY, SHORT)
    batch = na.EpisodeBatch.of(cfg, SEEDS, keep_cov=True)
    for k0 in (0.01, 6.309573444801936):
        assert_constant_kappa(cfg, SEEDS, vb.run_rule_on(batch, vb.VbRule("none", 3.0, k0)), k0)
    with pytest.raises(ValueError, match="keep_cov"):
        vb.run_rule_on(na.EpisodeBatch.of(cfg, SEEDS), vb.VbRule("r", 3.0, 1.0))


def test_the_tuned_rule_is_never_worse_than_the_best_constant_on_its_tuning_episodes() -> None:
    cfg = load_config(FAMILY, SHORT)
    tuning = [hs.episode(cfg, s) for s in range(1_000_000, 1_000_004)]
    rule, score = vb.tune_on(na.EpisodeBatch.of_episodes(cfg, tuning, keep_cov=True))
    assert_tuning_nests_the_constants(cfg, tuning, score, rule.kappa0, "vb-noise")
