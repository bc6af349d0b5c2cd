"""The Sage–Husa κ of the gyro UKF (``qkf.redundant_gyros.sage_husa``): its estimate is the
process noise exactly when the sample innovation is replaced by its expectation (a linear
random-walk filter by hand), the rule follows its equations stepped with filterpy's UKF, a rule
that never adapts is the constant κ, and the tuned rule is never worse than the best constant on
its tuning episodes (docs/redundant_gyros.md, "Sage–Husa κ")."""

from __future__ import annotations

import numpy as np
import pytest

from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros import nis_adaptive as na
from qkf.redundant_gyros import sage_husa as sh
from qkf.redundant_gyros.ukf import CalibrationUKF
from tests.gyro_rules import (
    assert_constant_kappa,
    assert_follows_by_hand,
    assert_tuning_nests_the_constants,
)

FAMILY = "gyro_noise_levels"
SHORT = ["scenario.duration_s=160"]  # judged from 100 s (hindsight.SETTLED_S)
SEEDS = [5_000_010, 5_000_011]


def test_the_estimate_is_the_process_noise_when_the_innovation_is_its_expectation() -> None:
    """Four scalar random-walk Kalman filters ``x_k = x_{k−1} + w``, ``z = x + v``, with
    ``Q = κ q² dt``: replacing ``ν²`` by ``S`` (``Δx̂ = K √S``) makes ``Δx̂² + P_k − P_{k−1}``
    equal to ``Q`` (``K S K = P⁻ − P_k``), so the period's estimate is ``κ`` whatever the prior,
    the noise and the step."""
    rng = np.random.default_rng(2)
    n, period = 3, 7
    q2 = rng.uniform(0.5, 2.0, 4)
    kappa = rng.uniform(0.1, 10.0, n)
    dt = rng.uniform(0.05, 0.2, (n, period))
    r = rng.uniform(0.1, 1.0, 4)
    p = rng.uniform(1.0, 50.0, (n, 4))
    x = rng.normal(size=(n, 4))
    x_prev, p_prev = x.copy(), np.stack([np.diag(row) for row in p])
    est, cov = np.empty((n, period, 4)), np.empty((n, period, 4, 4))
    for k in range(period):
        p_minus = p + kappa[:, None] * q2[None, :] * dt[:, k, None]
        s = p_minus + r
        gain = p_minus / s
        x = x + gain * np.sqrt(s) * rng.choice([-1.0, 1.0], (n, 4))
        p = (1.0 - gain) * p_minus
        est[:, k] = x
        cov[:, k] = np.stack([np.diag(row) for row in p])
    q_step = q2[None, None, :] * dt[:, :, None]
    got = sh.period_kappa_estimate(est, cov, x_prev, p_prev, q_step)
    np.testing.assert_allclose(got, kappa, rtol=1e-9)
    # epochs not run (NaN) are left out; an episode with none has no estimate
    est[1, 4:], cov[1, 4:], est[2], cov[2] = np.nan, np.nan, np.nan, np.nan
    got = sh.period_kappa_estimate(est, cov, x_prev, p_prev, q_step)
    np.testing.assert_allclose(got[:2], kappa[:2], rtol=1e-9)
    assert np.isnan(got[2])


def _by_hand(cfg, seed: int, rule: sh.SageHusaRule) -> float:  # type: ignore[no-untyped-def]
    """The rule stepped with filterpy's UKF, epoch by epoch, from the module's equations."""
    ep = hs.episode(cfg, seed)
    i, s = ep.inputs, ep.setup
    kappas = np.asarray(cfg.environment.actions.values())
    lo, hi = float(kappas.min()), float(kappas.max())
    q2 = np.asarray(s.q_sd, dtype=float) ** 2
    ukf = CalibrationUKF(s, float(i.dt[0]))
    kappa, total = rule.kappa0, 0.0
    for t, k0 in enumerate(range(0, ep.n_epochs, ep.period)):
        ratios = []
        for k in range(k0, min(k0 + ep.period, ep.n_epochs)):
            x_before, p_before = ukf.x.copy(), ukf.P.copy()
            res = ukf.step(float(i.z[k]), i.rate[k], float(i.dt[k]), kappa)
            assert res.ok
            dx = ukf.x - x_before
            q_hat = dx * dx + np.diag(ukf.P) - np.diag(p_before)  # Q̂_k,ii
            ratios.extend(q_hat / (q2 * float(i.dt[k])))
            if k >= ep.settled_from:
                total += float(np.sum(((ukf.x - i.truth[k]) / s.p0_sd) ** 2))
        step = t - rule.warm_up
        if step >= 0:
            held = float(np.clip(np.mean(ratios), lo, hi))
            d = 0.0 if rule.beta >= 1 else (1 - rule.beta) / (1 - rule.beta ** (step + 1))
            kappa = float(np.clip((1 - d) * kappa + d * held, lo, hi))
    return total / ((ep.n_epochs - ep.settled_from) * 4)


@pytest.mark.parametrize(
    "rule", [sh.SageHusaRule(0.8, 1.0, 0), sh.SageHusaRule(0.95, 0.1, 3)], ids=str
)
def test_rule_follows_its_equations(rule: sh.SageHusaRule) -> None:
    cfg = load_config(FAMILY, SHORT)
    batch = na.EpisodeBatch.of(cfg, SEEDS, keep_cov=True)
    assert_follows_by_hand(SEEDS, sh.run_rule_on(batch, rule), lambda s: _by_hand(cfg, s, rule))


def test_a_rule_that_never_adapts_is_the_constant_kappa() -> None:
    cfg = load_config(FAMILY, SHORT)
    batch = na.EpisodeBatch.of(cfg, SEEDS, keep_cov=True)
    for rule in (sh.SageHusaRule(1.0, 0.1), sh.SageHusaRule(0.5, 10.0, warm_up=10**6)):
        assert_constant_kappa(cfg, SEEDS, sh.run_rule_on(batch, rule), rule.kappa0)
    with pytest.raises(ValueError, match="keep_cov"):
        sh.run_rule_on(na.EpisodeBatch.of(cfg, SEEDS), sh.SageHusaRule(0.9, 1.0))


def test_the_tuned_rule_is_never_worse_than_the_best_constant_on_its_tuning_episodes() -> None:
    cfg = load_config(FAMILY, SHORT)
    tuning = [hs.episode(cfg, s) for s in range(1_000_000, 1_000_004)]
    rule, score = sh.tune_on(na.EpisodeBatch.of_episodes(cfg, tuning, keep_cov=True))
    assert_tuning_nests_the_constants(cfg, tuning, score, rule.kappa0, "sage-husa")
