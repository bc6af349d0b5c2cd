"""The clock yardstick (docs/methods.md, "Clock"): one open-loop κ(t) for every trial."""

from __future__ import annotations

import pickle

import numpy as np

from qkf.transfer_alignment.judging import estimate_scores, pooled
from qkf.transfer_alignment.methods.base import action_values, prepare
from qkf.transfer_alignment.methods.clock import ClockSchedule, describe, run_clock
from qkf.transfer_alignment.methods.fixed import tuned_kappa
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with


def test_clock_is_one_schedule_of_time_at_least_as_good_as_the_best_constant() -> None:
    cfg = cfg_with(
        "scenario.duration_s=900",
        "run.settled_s=300",
        "adaptive.actions.log10_min=-1",
        "adaptive.actions.log10_step=1",
        "adaptive.actions.count=3",
        "adaptive.tuned.trials=2",
        "adaptive.clock.block_s=300",
        "adaptive.clock.passes=2",
        base="thermal_snap.yaml",
    )
    method = prepare(run_clock, cfg)
    assert isinstance(method, ClockSchedule)
    assert method.block_s == 300.0 and len(method.kappa) == 3
    assert set(method.kappa) <= set(action_values(cfg).tolist())
    assert np.all(np.diff(method.tuning) <= 0.0)  # pooled score per stage
    # its tuning score, recomputed, is not above the best constant κ's (kf-tuned's choice)
    tuning = simulate(cfg, cfg.adaptive.tuned.seed, cfg.adaptive.tuned.trials)
    out = method(cfg, tuning)
    score = pooled(estimate_scores(cfg, out.est, tuning), out.diverged)
    np.testing.assert_allclose(score, method.tuning[-1], rtol=1e-10)
    _, constants = tuned_kappa(cfg)
    assert score <= min(constants) + 1e-12
    np.testing.assert_allclose(method.tuning[0], min(constants), rtol=1e-10)
    # on other trials: the same κ(t) for every trial, constant within each block
    data = simulate(cfg, 77, 3)
    out = method(cfg, data)
    assert out.kappa is not None
    assert np.all(out.kappa == out.kappa[:1])
    blocks = out.kappa.reshape(3, 3, 300)
    assert np.all(blocks == blocks[..., :1])
    np.testing.assert_array_equal(blocks[0, :, 0], method.kappa)
    same = run_schedule(cfg, data, np.ascontiguousarray(out.kappa))
    np.testing.assert_array_equal(out.est, same.est)
    assert "tuned with the truth on 2 trials" in out.notes["clock"]
    # prepared once in the driver, shipped to workers
    again = pickle.loads(pickle.dumps(method))
    assert again == method
    np.testing.assert_array_equal(again(cfg, data).est, out.est)


def test_schedule_by_time_and_its_description() -> None:
    clock = ClockSchedule(300.0, (40.0, 40.0, 0.4, 1.0))
    np.testing.assert_array_equal(
        clock.at(np.array([0.0, 299.0, 300.0, 650.0, 900.0, 5000.0])),
        [40.0, 40.0, 40.0, 0.4, 1.0, 1.0],
    )
    assert describe(300.0, clock.kappa) == "κ = 40 for 0–600 s, 0.4 for 600–900 s, 1 from 900 s"
