"""The hindsight yardstick (docs/methods.md, "Hindsight") and its search engine, against an
exhaustive search on a problem small enough to enumerate."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.judging import estimate_scores
from qkf.transfer_alignment.methods.alarm_burst import AlarmBurstSchedule
from qkf.transfer_alignment.methods.base import action_values, prepare, validate_output
from qkf.transfer_alignment.methods.clock import run_clock
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.methods.fixed import run_kf, run_kf_tuned
from qkf.transfer_alignment.methods.hindsight import (
    certificate,
    hindsight_plan,
    restart_schedule,
    run_hindsight,
)
from qkf.transfer_alignment.methods.oracle import OracleSchedule, run_oracle, run_schedule
from qkf.transfer_alignment.methods.schedule_search import snap, switches
from qkf.transfer_alignment.scenario import ScenarioData, simulate
from tests.conftest import cfg_with

TINY = (
    "scenario.duration_s=900",
    "run.settled_s=300",
    "adaptive.actions.log10_min=-1",
    "adaptive.actions.log10_step=1",
    "adaptive.actions.count=3",
)


def tiny(*sets: str) -> Config:
    """thermal_snap cut to 900 s with three actions (κ = 0.1, 1, 10)."""
    return cfg_with(*TINY, *sets, base="thermal_snap.yaml")


def scores_of(cfg: Config, data: ScenarioData, kappa: np.ndarray) -> np.ndarray:
    out = run_schedule(
        cfg, data, np.ascontiguousarray(np.broadcast_to(kappa, data.ads_q.shape[:2]))
    )
    return estimate_scores(cfg, out.est, data)


def test_two_blocks_against_every_schedule() -> None:
    # 2 blocks × 3 actions: 9 schedules, few enough to run them all
    cfg = tiny("adaptive.hindsight.period_s=450", "adaptive.hindsight.blocks_s=[450]",
               "adaptive.hindsight.passes=4")  # fmt: skip
    data = simulate(cfg, 21, 3)
    values = action_values(cfg)
    half = data.t >= 450.0 - 1e-9
    table = {
        (a, c): scores_of(cfg, data, np.where(half, values[c], values[a]))
        for a, c in itertools.product(range(3), repeat=2)
    }
    out = validate_output(
        run_hindsight(cfg, data), "hindsight", 3, data.n_epochs, covariance_epochs(cfg).size
    )
    got = estimate_scores(cfg, out.est, data)
    # the reported scores are those of the output
    np.testing.assert_allclose(out.logs["hindsight_scores"][:, -1], got, rtol=1e-10)
    assert out.kappa is not None and out.cov is not None
    for i in range(3):
        u = (
            int(np.argmin(np.abs(values - out.kappa[i, 0]))),
            int(np.argmin(np.abs(values - out.kappa[i, -1]))),
        )
        np.testing.assert_allclose(got[i], table[u][i], rtol=1e-10)
        # not worse than any constant, and coordinate-wise optimal (what the descent promises)
        assert got[i] <= min(table[(a, a)][i] for a in range(3)) + 1e-12
        for a in range(3):
            assert got[i] <= table[(a, u[1])][i] + 1e-12
            assert got[i] <= table[(u[0], a)][i] + 1e-12
        # on this problem it is also the exhaustive optimum
        np.testing.assert_allclose(got[i], min(v[i] for v in table.values()), rtol=1e-10)
    start = out.logs["hindsight_scores"][:, 0]
    np.testing.assert_allclose(start, [min(table[(a, a)][i] for a in range(3)) for i in range(3)])


def test_stages_never_get_worse_and_kappa_is_on_the_grid() -> None:
    cfg = tiny("adaptive.hindsight.period_s=50", "adaptive.hindsight.blocks_s=[300, 150, 50]",
               "adaptive.hindsight.focus_s=100", "adaptive.hindsight.restarts=0")  # fmt: skip
    data = simulate(cfg, 4, 2)
    out = run_hindsight(cfg, data)
    scores, stages = out.logs["hindsight_scores"], out.logs["hindsight_stages"]
    assert list(stages) == ["start", "300 s #1", "150 s #1", "50 s #1"]
    assert scores.shape == (2, 4)
    assert np.all(np.diff(scores, axis=1) <= 0.0)
    assert out.kappa is not None
    assert np.isin(out.kappa, action_values(cfg)).all()
    per_period = out.kappa.reshape(2, -1, 50)  # 900 epochs = 18 periods of 50 s
    assert np.all(per_period == per_period[..., :1])
    np.testing.assert_allclose(scores[:, -1], estimate_scores(cfg, out.est, data), rtol=1e-10)
    assert "hindsight" in out.notes and "per trial" in out.notes["hindsight"]


def test_restarts_keep_the_best_search_and_certify_the_spread() -> None:
    """Two restarts from random schedules: each trial's output is the best of the three
    searches' schedules, the certificate is their spread, and a restart's start is drawn per
    trial from its own seed (the same whatever batch the trial is in)."""
    cfg = tiny("adaptive.hindsight.period_s=50", "adaptive.hindsight.blocks_s=[300, 50]",
               "adaptive.hindsight.restarts=2")  # fmt: skip
    data = simulate(cfg, 4, 3)
    out = run_hindsight(cfg, data)
    final = out.logs["hindsight_searches"]
    assert final.shape == (3, 3)
    np.testing.assert_allclose(estimate_scores(cfg, out.est, data), final.min(axis=1), rtol=1e-10)
    spread = (final.max(axis=1) - final.min(axis=1)) / final.min(axis=1)
    np.testing.assert_allclose(certificate(final), spread, rtol=1e-12)
    note = out.notes["hindsight_certificate"]
    assert note.startswith("best κ schedule found: the best of 3 searches per trial")
    one = simulate(cfg, 4, [1])
    np.testing.assert_array_equal(
        restart_schedule(cfg, one, 2)[0], restart_schedule(cfg, data, 2)[1]
    )
    assert not np.array_equal(restart_schedule(cfg, data, 1), restart_schedule(cfg, data, 2))
    assert np.isin(restart_schedule(cfg, data, 1), action_values(cfg)).all()


def test_a_start_is_snapped_and_never_lost() -> None:
    cfg = tiny("adaptive.hindsight.period_s=150", "adaptive.hindsight.blocks_s=[450]",
               "adaptive.hindsight.restarts=0")  # fmt: skip
    data = simulate(cfg, 8, 2)
    values = action_values(cfg)
    # off the grid: 0.9 → 1, 12 → 10, and the value at each period's first epoch counts
    start = np.where(data.t < 300.0 - 1e-9, 12.0, 0.9)
    start[(data.t > 10.0) & (data.t < 20.0)] = 0.1  # inside a period: ignored
    grid = snap(cfg, np.broadcast_to(start, (2, data.n_epochs)), 150)
    np.testing.assert_array_equal(grid, [[2, 2, 1, 1, 1, 1]] * 2)
    snapped = np.repeat(values[grid[0]], 150)
    out = run_hindsight(cfg, data, starts=[start])
    got = estimate_scores(cfg, out.est, data)
    assert np.all(got <= scores_of(cfg, data, snapped) + 1e-12)
    np.testing.assert_allclose(
        out.logs["hindsight_scores"][:, 0],
        np.minimum(
            scores_of(cfg, data, snapped),
            np.min([scores_of(cfg, data, np.full(data.n_epochs, v)) for v in values], axis=0),
        ),
        rtol=1e-10,
    )


def test_switches_and_the_plan() -> None:
    near = switches(np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 1]), 2)
    np.testing.assert_array_equal(near, [0, 0, 1, 1, 1, 1, 0, 0, 0, 0])
    assert not switches(np.zeros(5, dtype=int), 3).any()
    plan = hindsight_plan(cfg_with(base="thermal_snap.yaml"))
    assert plan.period == 10 and plan.blocks == (40, 20, 10, 5, 2)
    assert plan.focus == (None, None, None, 10, 10)  # the defaults: focus below 100 s
    with pytest.raises(ConfigError, match="blocks_s"):
        tiny("adaptive.hindsight.blocks_s=[400, 25]")


@pytest.mark.slow  # 3 trials of a 1800 s run, and the tuning of clock, oracle and kf-tuned
def test_hindsight_is_below_the_other_schedules_per_trial() -> None:
    """Per trial (3 here), the bound is at or below (within 0.5 %) every other κ schedule:
    the fixed and tuned KF, the clock, the oracle, alarm-burst and the shipped policy. (The
    many-trial check runs on a families study: benchmarks/hindsight_bound.py.)"""
    from agents.policy import run_policy

    # the others are tuned on 2 trials here: the bound must hold however well they are tuned;
    # the family's run at half its length, the snap moved into it (the bound holds per trial
    # whatever the length; the full length is the benchmark's)
    cfg = cfg_with("adaptive.tuned.trials=2", "scenario.duration_s=1800",
                   "scenario.random_events.jump.t_s.low=600",
                   "scenario.random_events.jump.t_s.high=1300",
                   base="thermal_snap_random.yaml")  # fmt: skip
    data = simulate(cfg, 5_000_000, 3)
    bound = estimate_scores(cfg, run_hindsight(cfg, data).est, data)
    oracle = prepare(run_oracle, cfg)
    assert isinstance(oracle, OracleSchedule)
    # alarm-burst is the oracle's schedule started by an alarm: its tuning is the oracle's
    methods = (run_kf, prepare(run_kf_tuned, cfg), prepare(run_clock, cfg), oracle,
               AlarmBurstSchedule(oracle),
               lambda c, d: run_policy(c, d, "agents/zoo/best/model.zip"))  # fmt: skip
    for method in methods:
        other = estimate_scores(cfg, method(cfg, data).est, data)
        below = np.mean(bound <= 1.005 * other)
        assert below >= 0.95, (method, bound, other)


def test_stopping_hopeless_candidates_changes_nothing() -> None:
    """A candidate stopped once its sum reaches the incumbent's (SearchPlan.stop_early) could
    not have won, so the search takes the same decisions, bit for bit, with fewer epochs."""
    from dataclasses import replace

    from qkf.transfer_alignment.methods.schedule_search import search

    cfg = tiny("adaptive.hindsight.period_s=50", "adaptive.hindsight.blocks_s=[300, 150, 50]",
               "adaptive.hindsight.passes=2")  # fmt: skip
    data = simulate(cfg, 5, 5)  # 5 trials: the parallel kernel, then fewer rows as they stop
    plan = hindsight_plan(cfg)
    slow = search(cfg, data, replace(plan, stop_early=False))
    fast = search(cfg, data, plan)
    np.testing.assert_array_equal(fast.choice, slow.choice)
    np.testing.assert_array_equal(fast.scores, slow.scores)
    assert slow.stopped == 0 < fast.stopped
    assert fast.trial_epochs < slow.trial_epochs


def test_screening_keeps_the_best_of_each_trial_and_never_loses_ground() -> None:
    from qkf.transfer_alignment.methods.schedule_search import _lowest_per_group

    groups = np.array([0, 0, 0, 1, 1, 2])
    values = np.array([3.0, 1.0, np.nan, 2.0, 2.0, 5.0])
    # per trial the `keep` lowest; ties go to the earlier row, a lost (NaN) row ranks last
    np.testing.assert_array_equal(
        _lowest_per_group(groups, values, 2), [True, True, False, True, True, True]
    )
    np.testing.assert_array_equal(
        _lowest_per_group(groups, values, 1), [False, True, False, True, False, True]
    )
    cfg = tiny("adaptive.hindsight.period_s=50", "adaptive.hindsight.blocks_s=[300, 150, 50]",
               "adaptive.hindsight.screen_s=100", "adaptive.hindsight.screen_keep=1")  # fmt: skip
    out = run_hindsight(cfg, simulate(cfg, 5, 3))
    scores = out.logs["hindsight_scores"]
    assert np.all(np.diff(scores, axis=1) <= 0.0)  # a screened candidate is still judged whole
    assert "stopped" in out.notes["hindsight"]
