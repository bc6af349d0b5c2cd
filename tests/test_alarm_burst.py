"""The alarm-burst method: its NIS statistic by hand, its κ trace against the same rule run
through the environment's observation v2 (an independent path to the NIS), and its estimates
against the fixed-schedule filter (docs/methods.md, "Alarm burst")."""

from __future__ import annotations

import numpy as np
import pytest

from envs.transfer_alignment.episodes import BatchedEpisodes
from envs.transfer_alignment.observations import TIME_SCALE_S
from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.methods import BUILTIN_METHODS, METHODS
from qkf.transfer_alignment.methods.alarm_burst import AlarmBurstSchedule, nis_per_row
from qkf.transfer_alignment.methods.oracle import OracleSchedule, run_schedule
from qkf.transfer_alignment.scenario import ScenarioData, simulate

SCHEDULE = OracleSchedule(base=2.5, after=100.0, window_s=50.0)


def v2_rule_kappa(
    cfg: Config, data: ScenarioData, schedule: OracleSchedule = SCHEDULE
) -> np.ndarray:
    """κ per epoch of the alarm-burst rule acting on the environment's v2 observation (entry 12,
    the change's age): κ_after while the change is younger than the window, else κ_base."""
    core = BatchedEpisodes(cfg, data.n_trials, "oracle", 10.0, observation="v2")
    obs = core.load(data)
    below = np.log10(1.0 + schedule.window_s / TIME_SCALE_S) - 1e-6
    trace = []
    for _ in range(0, data.n_epochs, core.period):
        kappa = np.where(obs[:, 12] < below, schedule.after, schedule.base)
        trace.append(kappa)
        obs = core.step(kappa, np.zeros(data.n_trials)).obs
    return np.repeat(np.stack(trace, axis=1), core.period, axis=1)[:, : data.n_epochs]


def test_nis_per_row_by_hand() -> None:
    nis = np.array([[6.0, 12.0, np.nan], [np.nan, np.nan, np.nan], [np.inf, 0.0, 6.0]])
    # (6 + 12) / 2 / 6; no finite value → 1; the infinite epoch is left out: (0 + 6) / 2 / 6
    np.testing.assert_allclose(nis_per_row(nis, 6), [1.5, 1.0, 0.5])


@pytest.mark.slow  # whole 3600 s runs through the method and the environment
def test_kappa_trace_matches_the_v2_rule_and_the_schedule_filter() -> None:
    cfg = load_config("thermal_snap_random")
    data = simulate(cfg, 3, 4)
    out = AlarmBurstSchedule(SCHEDULE)(cfg, data)
    assert out.kappa is not None
    # the same rule acting on the environment's v2 observation (entry 12, the change's age)
    env_kappa = v2_rule_kappa(cfg, data)
    np.testing.assert_array_equal(out.kappa, env_kappa)
    assert data.jump_t is not None
    for row in range(data.n_trials):
        burst = np.flatnonzero(out.kappa[row] == SCHEDULE.after)
        # one window of W seconds, opened by the jump within a few periods of it
        assert burst.size == round(SCHEDULE.window_s / cfg.scenario.dt_s)
        assert np.all(np.diff(burst) == 1)
        assert 0.0 < data.t[burst[0]] - data.jump_t[row] <= 60.0
    ref = run_schedule(cfg, data, out.kappa)
    np.testing.assert_allclose(out.est, ref.est, rtol=0, atol=1e-12)


def test_registered_by_name_but_not_in_all() -> None:
    assert "alarm-burst" in METHODS and "alarm-burst" not in BUILTIN_METHODS


def test_zero_quiet_restarts_at_every_alarm() -> None:
    """With no calm required every alarm is a new change: the burst is re-opened each time."""
    cfg = load_config("thermal_snap_random", ["adaptive.alarm_burst.quiet_s=0"])
    data = simulate(cfg, 3, 2)
    out = AlarmBurstSchedule(SCHEDULE)(cfg, data)
    default = AlarmBurstSchedule(SCHEDULE)(load_config("thermal_snap_random"), data)
    assert out.kappa is not None and default.kappa is not None
    assert (out.kappa == SCHEDULE.after).sum() > (default.kappa == SCHEDULE.after).sum()
