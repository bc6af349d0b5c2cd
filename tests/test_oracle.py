"""The oracle schedule (docs/methods.md, "Oracle schedule") and the truth it reads."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from qkf.transfer_alignment.methods import BUILTIN_METHODS, METHODS
from qkf.transfer_alignment.methods.oracle import (
    run_schedule,
    schedule,
    settled_score,
    tune_oracle,
)
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with


def test_jump_time_is_where_the_true_calibration_steps() -> None:
    cfg = cfg_with(base="thermal_snap_random.yaml")
    data = simulate(cfg, 11, 4)
    assert data.jump_t is not None and np.all(np.isfinite(data.jump_t))
    assert len(set(np.round(data.jump_t, 6))) == 4  # drawn per trial
    step = np.abs(np.diff(data.calib, axis=1)).max(axis=-1)  # (B, N-1)
    k = np.argmax(step, axis=1) + 1  # the epoch where the largest step has happened
    np.testing.assert_allclose(data.t[k], data.jump_t, atol=data.dt + 1e-9)
    assert np.isnan(simulate(cfg_with(), 0, 1).jump_t).all()  # paper: no jump


def test_schedule_by_hand() -> None:
    cfg = cfg_with("scenario.duration_s=100", base="thermal_snap.yaml")
    data = dataclasses.replace(simulate(cfg, 0, 2), jump_t=np.array([10.0, np.nan]))
    kap = schedule(data, 1.0, 50.0, 5.0)
    inside = (data.t >= 10.0 - 1e-9) & (data.t < 15.0 - 1e-9)
    np.testing.assert_array_equal(kap[0], np.where(inside, 50.0, 1.0))
    np.testing.assert_array_equal(kap[1], 1.0)


@pytest.mark.slow  # runs the oracle's whole tuning grid twice over
def test_oracle_is_the_best_of_its_grid_on_the_tuning_trials() -> None:
    cfg = cfg_with(
        "scenario.duration_s=1500",
        "run.settled_s=400",
        "adaptive.tuned.trials=3",
        "adaptive.oracle.windows_s=[100, 400]",
        "adaptive.actions.log10_min=-1",
        "adaptive.actions.log10_step=1",
        "adaptive.actions.count=3",
        "scenario.random_events.jump.t_s.low=600",
        "scenario.random_events.jump.t_s.high=900",
        base="thermal_snap_random.yaml",
    )
    chosen = tune_oracle(cfg)
    data = simulate(cfg, cfg.adaptive.tuned.seed, cfg.adaptive.tuned.trials)

    def score(base: float, after: float, window: float) -> float:
        kappa = schedule(data, base, after, window)
        return settled_score(cfg, data, run_schedule(cfg, data, kappa))

    best = score(chosen.base, chosen.after, chosen.window_s)
    for after in (0.1, 1.0, 10.0):
        for window in (100.0, 400.0):
            assert best <= score(chosen.base, after, window) + 1e-15
    for base in (0.1, 1.0, 10.0):  # κ_base: the best constant κ
        assert score(chosen.base, chosen.base, 0.0) <= score(base, base, 0.0) + 1e-15


def test_oracle_is_registered_but_not_in_all() -> None:
    assert "oracle" in METHODS and "oracle" not in BUILTIN_METHODS
