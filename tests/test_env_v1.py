"""The v1 and v2 environments: their observation statistics by hand, the gain rewards against
an independent run of the methods, and registration (docs/environment.md)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import envs
from envs.transfer_alignment.episodes import BatchedEpisodes
from envs.transfer_alignment.observations import (
    CUSUM_DRIFT,
    OBSERVATIONS,
    ONSET_CAP_S,
    TIME_SCALE_S,
    ObservationV1,
    ObservationV2,
    PeriodView,
)
from qkf.core.stats import interquartile_mean
from qkf.transfer_alignment.alarms import NIS_ALARM, QUIET_S
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.filter import FilterRecord
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.metrics import state_errors, window_masks
from qkf.transfer_alignment.scenario import simulate

SHORT = ["scenario.duration_s=600", "run.settled_s=200"]


def _view(nis_per_row: float, rate_deg_s: np.ndarray, n_meas: int = 6, p: int = 10) -> PeriodView:
    """One period of one episode whose every epoch has the given NIS per row and rate."""
    rec = FilterRecord(
        est=np.zeros((1, p, 16)),
        var=np.ones((1, p, 15)),
        cov=None,
        dx=np.zeros((1, p, 15)),
        innov=np.zeros((1, p, 6)),
        nis_att=np.full((1, p), 3.0 * nis_per_row),
        nis_rate=np.full((1, p), 3.0 * nis_per_row),
        nis=np.full((1, p), n_meas * nis_per_row),
        logdet_s=np.zeros((1, p)),
        trace_s_att=np.zeros((1, p)),
        rate=np.broadcast_to(np.radians(rate_deg_s), (1, p, 3)).copy(),
    )
    return PeriodView(
        record=rec,
        valid=np.ones((1, p), bool),
        last=np.array([p - 1]),
        steps=np.array([p]),
        loglik_gain=None,
        elapsed=np.array([0.5]),
        kappa_pos=np.array([0.25]),
        p0_sigma=np.ones(15),
        n_meas=n_meas,
        dt=1.0,
    )


def test_v1_statistics_follow_a_hand_computation() -> None:
    obs_v1 = ObservationV1(load_config("paper"), 1, 10.0)  # the default alarm settings
    first = obs_v1.reset(np.array([0]), 0.5)
    assert first.shape == (1, 12) and first[0, 11] == 0.5 and not first[0, :11].any()
    still, turn = np.array([0.0, 0.0, 0.06]), np.array([1.0, 0.0, 0.06])
    # (NIS per row, rate) per period: calm, calm, a jump seen while turning, calm, calm
    script = [(1.0, still), (1.0, still), (20.0, turn), (3.0, turn), (1.0, turn)]
    cusum, since_alarm, since_change, window = 0.0, 0.0, 0.0, [1.0] * 6
    last_rate = None
    for x, rate in script:
        o = obs_v1(_view(x, rate))[0]
        cusum = max(0.0, cusum + x - 1.0 - CUSUM_DRIFT)
        since_alarm = 0.0 if x > NIS_ALARM else since_alarm + 10.0
        moved = last_rate is not None and np.linalg.norm(rate - last_rate) > 0.2
        since_change = 0.0 if moved else since_change + 10.0
        last_rate = rate
        window = [*window[1:], x]
        np.testing.assert_allclose(o[3:5], np.log10(x), atol=1e-6)
        assert o[5] == pytest.approx(np.log10(np.mean(window)), abs=1e-6)
        assert o[6] == pytest.approx(np.log10(1 + cusum), abs=1e-6)
        assert o[7] == pytest.approx(np.log10(1 + since_alarm / TIME_SCALE_S), abs=1e-6)
        assert o[8] == pytest.approx(np.linalg.norm(rate), abs=1e-5)
        assert o[9] == pytest.approx(np.log10(1 + since_change / TIME_SCALE_S), abs=1e-6)
        assert o[10] == pytest.approx(0.5) and o[11] == pytest.approx(0.25)
    assert cusum == pytest.approx(18.0)  # 0, 0, 20 − 2 = 18, +1 at x = 3, −1 when calm again


def test_v2_change_age_follows_a_hand_computation() -> None:
    """The age restarts at an alarm after ≥ QUIET_S of calm only: the alarms that the same
    change raises at the following rotation axes do not restart it."""
    cfg = load_config("paper")  # the default alarm settings: NIS_ALARM, QUIET_S
    obs_v1, obs_v2 = ObservationV1(cfg, 1, 10.0), ObservationV2(cfg, 1, 10.0)
    first = obs_v2.reset(np.array([0]), 0.5)
    obs_v1.reset(np.array([0]), 0.5)
    assert first.shape == (1, 13) and first[0, 11] == 0.5
    assert first[0, 12] == pytest.approx(np.log10(1 + ONSET_CAP_S / TIME_SCALE_S))
    quiet_periods = int(QUIET_S // 10)
    calm, alarm = 1.0, 20.0
    # calm; a change raising alarms at three axes 60 s apart; calm for QUIET_S − 10 s and an
    # alarm (same change); calm for QUIET_S and an alarm (a new change)
    script = [calm] * 3 + [alarm] + [calm] * 5 + [alarm] + [calm] * 5 + [alarm]
    script += [calm] * (quiet_periods - 1) + [alarm] + [calm] * quiet_periods + [alarm, calm]
    age, quiet, ages = np.inf, np.inf, []
    rate = np.array([0.0, 0.0, 0.06])
    for x in script:
        view = _view(x, rate)
        o1, o2 = obs_v1(view)[0], obs_v2(view)[0]
        if x > NIS_ALARM:
            age = 0.0 if quiet >= QUIET_S else age + 10.0
            quiet = 0.0
        else:
            age, quiet = age + 10.0, quiet + 10.0
        ages.append(age)
        np.testing.assert_array_equal(o2[:12], o1)  # v2 extends v1
        assert o2[12] == pytest.approx(np.log10(1 + min(age, ONSET_CAP_S) / TIME_SCALE_S))
    restarts = [i for i, a in enumerate(ages) if a == 0.0]
    assert restarts == [3, len(script) - 2]  # the first alarm and the one after the long calm


def test_v1_is_registered_with_its_observation() -> None:
    env = gym.make("qkf/TransferAlignment-v1", scenario="paper", overrides=SHORT)
    assert env.observation_space.shape == (OBSERVATIONS["v1"].size,)
    obs, _ = env.reset(seed=3)
    for _ in range(5):
        obs, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
    assert np.all(np.abs(obs[:10]) < 5.0)  # order one, unlike v0's likelihood feature
    vec = gym.make_vec("qkf/TransferAlignment-v1", num_envs=2, scenario="paper", overrides=SHORT)
    assert vec.single_observation_space.shape == (12,)
    assert envs.TA_ENV_OBSERVATIONS["qkf/TransferAlignment-v0"] == "v0"
    v2 = gym.make("qkf/TransferAlignment-v2", scenario="paper", overrides=SHORT)
    assert v2.observation_space.shape == (13,)
    obs, _ = v2.reset(seed=3)
    assert v2.observation_space.contains(obs)


@pytest.mark.parametrize(
    ("reward", "states"), [("misalignment_gain", slice(9, 15)), ("calibration_gain", slice(6, 15))]
)
def test_gain_reward_sums_to_the_settled_mse_reduction(reward: str, states: slice) -> None:
    """An episode's return is MSE_kf − MSE_agent over the settled window (display units²),
    checked against the two filters run independently as benchmark schedules."""
    cfg = load_config("thermal_snap", SHORT)
    data = simulate(cfg, 11, 3)
    core = BatchedEpisodes(cfg, 3, reward, 10.0, observation="v1")
    core.load(data)
    kappa = np.array([2.5, 0.1, 40.0])
    total = np.zeros(3)
    for _ in range(core.episode_steps):
        total += core.step(kappa, np.zeros(3)).reward
    settled = window_masks(data.t, cfg.run.settled_s)["settled"]
    unit = np.array([1e-6] * 3 + [1e-6] * 6)[: states.stop - states.start]

    def mse(k: np.ndarray) -> np.ndarray:
        out = run_schedule(cfg, data, np.broadcast_to(k[:, None], (3, data.n_epochs)).copy())
        err = state_errors(out.est, data.q_true, data.bias, data.calib)[:, settled, states] / unit
        return np.mean(err**2, axis=(1, 2))

    np.testing.assert_allclose(total, mse(np.ones(3)) - mse(kappa), rtol=1e-6, atol=1e-9)
    assert np.all(total[[1]] < 0.0)  # κ = 0.1 cannot follow the snap: worse than kf


def test_interquartile_mean_by_hand() -> None:
    assert interquartile_mean(np.array([3.0, 1.0, 2.0])) == pytest.approx((1 + 4 * 2 + 3) / 6)
    assert interquartile_mean(np.array([1.0, 2.0, 3.0, 100.0])) == pytest.approx(2.5)
    assert interquartile_mean(np.arange(8.0)) == pytest.approx(np.mean([2, 3, 4, 5]))
    with pytest.raises(ValueError):
        interquartile_mean(np.array([1.0, np.nan]))
