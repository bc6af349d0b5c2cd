"""``qkf/RedundantGyroCalibration-v0``: Gymnasium's and SB3's env checkers, seeding, episode
length from the config, the likelihood reward's reference, actions, and ``qkf train``."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from typer.testing import CliRunner

import envs
from agents.config import TrainConfig, validate_train_config
from envs.redundant_gyros import GYRO_REWARDS, RedundantGyroCalibrationEnv
from qkf.cli import app
from qkf.core.config import ConfigError

SHORT = ["scenario.duration_s=90"]  # fault at 60 s: 300 calibrated epochs, 3 periods of 10 s


@pytest.mark.parametrize(
    "kwargs",
    [{}, {"action_type": "continuous"}, {"reward": "oracle"}, {"reward": "nees"}],
)
def test_env_checkers_pass_without_warnings(kwargs: dict[str, str]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # v0 is kept for its policies; Gymnasium warns that v1 supersedes it
        warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)
        check_env(gym.make(envs.GYRO_ENV_ID, overrides=SHORT, **kwargs).unwrapped)
        sb3_check_env(RedundantGyroCalibrationEnv(overrides=SHORT, **kwargs), warn=True)


def test_registration_and_rewards() -> None:
    env = gym.make("qkf/RedundantGyroCalibration-v0", overrides=SHORT)
    assert env.spec is not None and env.spec.id == envs.GYRO_ENV_ID
    assert isinstance(env.unwrapped, RedundantGyroCalibrationEnv)
    assert {"likelihood", "oracle", "nees"} <= set(GYRO_REWARDS)
    assert not GYRO_REWARDS["likelihood"].uses_truth and GYRO_REWARDS["oracle"].uses_truth


def _episode(env: gym.Env, seed: int, action: int) -> tuple[list[np.ndarray], list[float]]:  # type: ignore[type-arg]
    obs, _ = env.reset(seed=seed)
    seen, rewards = [obs], []
    done = False
    while not done:
        obs, r, term, trunc, _ = env.step(action)
        seen.append(obs)
        rewards.append(float(r))
        done = term or trunc
    return seen, rewards


def test_same_seed_same_episode_other_seed_another() -> None:
    env = gym.make(envs.GYRO_ENV_ID, overrides=SHORT)
    a = _episode(env, 5, 3)
    b = _episode(env, 5, 3)
    c = _episode(env, 6, 3)
    np.testing.assert_array_equal(np.array(a[0]), np.array(b[0]))
    assert a[1] == b[1]
    assert not np.array_equal(np.array(a[0]), np.array(c[0]))


@pytest.mark.parametrize(
    ("duration", "period", "steps"), [(90, 10.0, 3), (95, 10.0, 4), (90, 7.0, 5)]
)
def test_episode_length_follows_the_config(duration: float, period: float, steps: int) -> None:
    env = gym.make(envs.GYRO_ENV_ID, overrides=[f"scenario.duration_s={duration}"], period_s=period)
    assert env.unwrapped.episode_steps == steps  # type: ignore[attr-defined]
    env.reset(seed=0)
    for k in range(steps):
        _, _, term, trunc, info = env.step(5)
        assert not term and trunc == (k == steps - 1)
    assert info["t_s"] == pytest.approx(duration - 0.1)


def test_period_from_the_config() -> None:
    env = RedundantGyroCalibrationEnv(overrides=[*SHORT, "environment.period_s=15"])
    assert env.period == 150 and env.episode_steps == math.ceil(300 / 150)


def test_likelihood_reward_is_zero_at_the_nominal_kappa_and_not_elsewhere() -> None:
    """The reward compares the agent's filter with a κ = 1 copy run from the same state: at
    κ = 1 they coincide exactly; at κ = 100 they do not."""
    env = RedundantGyroCalibrationEnv(overrides=SHORT)
    nominal = env.cfg.environment.actions.nominal_index()
    assert env.actions.kappas[nominal] == pytest.approx(1.0)
    obs, rewards = _episode(env, 1, nominal)
    assert rewards == [0.0] * env.episode_steps
    assert all(o[5] == 0.0 for o in obs)
    _, other = _episode(env, 1, env.actions.kappas.size - 1)
    assert all(r != 0.0 for r in other)


def test_observation_is_in_range_and_informative() -> None:
    env = RedundantGyroCalibrationEnv(overrides=SHORT, reward="oracle")
    obs, rewards = _episode(env, 2, 5)
    for o in obs:
        assert env.observation_space.contains(o)
    last = obs[-1]
    assert np.all(last[:4] < -1.0)  # the UKF has converged well below its prior sd
    assert 0.2 < last[4] < 5.0  # NIS near 1
    assert last[6] == pytest.approx(1.0)
    assert rewards[-1] > -1.0  # the error is well inside the prior sd


@pytest.mark.parametrize("bad", [-1, 11, 2.5, "a", np.array([1, 2])])
def test_invalid_discrete_action_raises(bad: object) -> None:
    env = RedundantGyroCalibrationEnv(overrides=SHORT)
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(bad)


def test_step_before_reset_and_unknown_reward() -> None:
    with pytest.raises(RuntimeError, match="reset"):
        RedundantGyroCalibrationEnv(overrides=SHORT).step(0)
    with pytest.raises(ValueError, match="unknown reward"):
        RedundantGyroCalibrationEnv(overrides=SHORT, reward="nope")
    with pytest.raises(ValueError, match="no gyro to calibrate"):
        RedundantGyroCalibrationEnv("five_gyros", overrides=SHORT)


def test_training_config_checks_the_gyro_env() -> None:
    base = {"agent": "ppo", "env": envs.GYRO_ENV_ID, "scenario": "five_gyros_s_bias"}
    validate_train_config(TrainConfig.model_validate(base), "t.yaml")
    for extra, message in [
        ({"scenario": "five_gyros"}, "no gyro to calibrate"),
        ({"scenario": "paper"}, "scenario:"),
        ({"overrides": ["scenario.dt_s=-1"]}, "overrides:"),
    ]:
        with pytest.raises(ConfigError, match=message):
            validate_train_config(TrainConfig.model_validate({**base, **extra}), "t.yaml")


def test_qkf_train_trains_on_the_gyro_env(tmp_path: Path) -> None:
    out = tmp_path / "train"
    res = CliRunner().invoke(app, ["train", "train_gyros_ppo", "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    assert (out / "model.zip").is_file()
    assert "RedundantGyroCalibration" in (out / "config.yaml").read_text()
    with np.load(out / "eval" / "evaluations.npz") as ev:
        assert ev["ep_lengths"].shape[-1] == 2 and np.all(ev["ep_lengths"] == 4)
