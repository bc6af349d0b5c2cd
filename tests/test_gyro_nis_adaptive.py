"""The innovation-based adaptive κ of the gyro UKF (``qkf.redundant_gyros.nis_adaptive``) and
the ``mean_square`` reward, against hand computations with filterpy's UKF
(docs/redundant_gyros.md, "Innovation-based adaptive κ")."""

from __future__ import annotations

import numpy as np
import pytest

from envs.redundant_gyros.episodes import GyroEpisodes
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros import nis_adaptive as na
from qkf.redundant_gyros.ukf import CalibrationUKF
from tests.gyro_rules import assert_constant_kappa, assert_follows_by_hand

FAMILY = "gyro_noise_levels"
SHORT = ["scenario.duration_s=160"]  # judged from 100 s (hindsight.SETTLED_S)
SEEDS = [5_000_010, 5_000_011]


def _by_hand(cfg, seed: int, rule: na.NisRule) -> float:  # type: ignore[no-untyped-def]
    """The rule stepped with filterpy's UKF, epoch by epoch, from the module's equations."""
    ep = hs.episode(cfg, seed)
    i, s = ep.inputs, ep.setup
    kappas = np.asarray(cfg.environment.actions.values())
    ukf = CalibrationUKF(s, float(i.dt[0]))
    a = 1.0 - 2.0 ** (-1.0 / rule.halflife)
    kappa, m, total = rule.kappa0, 0.0, 0.0
    for k0 in range(0, ep.n_epochs, ep.period):
        nis = []
        for k in range(k0, min(k0 + ep.period, ep.n_epochs)):
            res = ukf.step(float(i.z[k]), i.rate[k], float(i.dt[k]), kappa)
            assert res.ok
            nis.append(res.innovation**2 / res.variance)
            if k >= ep.settled_from:
                total += float(np.sum(((ukf.x - i.truth[k]) / s.p0_sd) ** 2))
        m = (1 - a) * m + a * np.log(np.mean(nis))
        kappa = float(np.clip(kappa * np.exp(rule.gamma * m), kappas.min(), kappas.max()))
    return total / ((ep.n_epochs - ep.settled_from) * 4)


@pytest.mark.parametrize("rule", [na.NisRule(1.0, 1.0, 1.0), na.NisRule(2.0, 3.0, 0.01)])
def test_rule_follows_its_equations(rule: na.NisRule) -> None:
    cfg = load_config(FAMILY, SHORT)
    assert_follows_by_hand(SEEDS, na.run_rule(cfg, SEEDS, rule), lambda s: _by_hand(cfg, s, rule))


def test_a_rule_without_gain_is_the_constant_kappa() -> None:
    cfg = load_config(FAMILY, SHORT)
    for k0 in (0.01, 1.0, 100.0):
        assert_constant_kappa(cfg, SEEDS, na.run_rule(cfg, SEEDS, na.NisRule(0.0, 3.0, k0)), k0)


def test_tuning_grid_has_the_budget_and_picks_its_best() -> None:
    cfg = load_config(FAMILY, SHORT)
    n_points = len(na.GAINS) * len(na.HALF_LIVES) * len(cfg.environment.actions.values())
    assert n_points >= 50  # the like-for-like budget of the tuned baselines
    rule, score = na.tune(cfg, SEEDS)
    assert score == pytest.approx(float(np.mean(na.run_rule(cfg, SEEDS, rule))), rel=1e-12)
    kappas = cfg.environment.actions.values()
    constants = [np.mean(na.run_rule(cfg, SEEDS, na.NisRule(0.0, 1.0, k))) for k in kappas]
    assert score <= min(constants)  # the grid nests the constant κ


def test_mean_square_reward_sums_to_the_hindsight_criterion() -> None:
    """Over the settled periods the mean_square rewards add up to J × the settled epochs."""
    cfg = load_config(FAMILY, ["scenario.duration_s=100"])
    eps = GyroEpisodes(1, cfg, reward="mean_square", observation="v2")
    eps.rngs[0] = np.random.default_rng(SEEDS[0])
    eps.reset_envs(np.array([0]))
    kappa = eps.actions.kappas[7]
    rewards = [float(eps.run(np.array([kappa]), np.array([0.7])).reward[0]) for _ in range(10)]
    ep = hs.episode(cfg, SEEDS[0], settled_s=0.0)
    ukf = hs.CompiledUKF(ep)
    x, p = ukf.prior()
    j = ukf.score(ukf.run(x, p, np.full(ep.n_epochs, kappa), 0, ep.n_epochs))
    assert -np.mean(rewards) == pytest.approx(j, rel=1e-9)
