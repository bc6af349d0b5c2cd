"""Gymnasium environments: API checkers, seeding, the vector env against single envs,
bad actions and divergence."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import envs
from envs import (
    ENV_ID,
    ENV_ID_V1,
    ENV_ID_V2,
    BatchedTransferAlignmentEnv,
    TransferAlignmentEnv,
)

SHORT = ["scenario.duration_s=400"]


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"action_type": "continuous"},
        {"reward": "oracle"},
        {"reward": "nees"},
        {"reward": "misalignment_gain"},
    ],
    ids=["discrete", "continuous", "oracle", "nees", "gain"],
)
@pytest.mark.parametrize("env_id", [ENV_ID, ENV_ID_V1, ENV_ID_V2])
def test_env_checkers_pass_without_warnings(env_id: str, kwargs: dict[str, str]) -> None:
    obs = envs.TA_ENV_OBSERVATIONS[env_id]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # Gymnasium's own hint that v1 exists is the one warning v0 gives (by design)
        warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)
        check_env(gym.make(env_id, overrides=SHORT, **kwargs).unwrapped)
        sb3_check_env(TransferAlignmentEnv(overrides=SHORT, observation=obs, **kwargs), warn=True)


def test_registration() -> None:
    env = gym.make(ENV_ID, scenario="thermal_snap")
    assert env.unwrapped.episode_steps == 360  # type: ignore[attr-defined]
    assert isinstance(env.unwrapped, TransferAlignmentEnv)
    assert env.unwrapped.cfg.name == "thermal-snap"
    assert env.action_space == gym.spaces.Discrete(11)
    vec = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point")
    assert isinstance(vec.unwrapped, BatchedTransferAlignmentEnv)


def _episode(env: TransferAlignmentEnv, seed: int, actions: list[int]) -> list[tuple]:
    out = [env.reset(seed=seed)[0]]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append((obs, r, term, trunc, info["errors"]))
    return out


def test_same_seed_same_episode() -> None:
    actions = [5, 0, 10, 3] * 10
    a = _episode(TransferAlignmentEnv(overrides=SHORT), 7, actions)
    b = _episode(TransferAlignmentEnv(overrides=SHORT), 7, actions)
    c = _episode(TransferAlignmentEnv(overrides=SHORT), 8, actions)
    for x, y in zip(a[1:], b[1:], strict=True):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1] == y[1]
        np.testing.assert_array_equal(x[4], y[4])
    assert not np.array_equal(a[5][4], c[5][4])
    # 40 periods of 10 s end the 400 s episode
    assert a[-1][3] is True and not any(step[3] for step in a[1:-1])


def test_vector_env_equals_single_envs_step_for_step() -> None:
    n = 3
    vec = BatchedTransferAlignmentEnv(n, overrides=SHORT)
    singles = [TransferAlignmentEnv(overrides=SHORT) for _ in range(n)]
    obs, _ = vec.reset(seed=10)
    np.testing.assert_array_equal(
        obs, np.stack([e.reset(seed=10 + i)[0] for i, e in enumerate(singles)])
    )
    rng = np.random.default_rng(0)
    for step in range(45):  # past the end: next-step autoreset included
        a = rng.integers(0, 11, n)
        o, r, _, tr, _ = vec.step(a)
        ref = []
        for i, e in enumerate(singles):
            if step == 40:  # the singles ended on the previous step: reset as the vector env did
                ref.append((e.reset()[0], 0.0, False, False))
            else:
                ref.append(e.step(int(a[i]))[:4])
        np.testing.assert_array_equal(o, np.stack([x[0] for x in ref]), err_msg=f"step {step}")
        np.testing.assert_array_equal(r, [x[1] for x in ref])
        np.testing.assert_array_equal(tr, [x[3] for x in ref])


@pytest.mark.parametrize("bad", [np.nan, 11, -1, 2.5, "x", True, np.int64(11), np.array([1, 2])])
def test_invalid_discrete_action_raises(bad: object) -> None:
    env = TransferAlignmentEnv(overrides=SHORT)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(bad)


def test_discrete_action_forms_agree() -> None:
    """An index as a Python int, a numpy integer, a 0-d or 1-element array or an integral float
    selects the same κ."""
    env = TransferAlignmentEnv(overrides=SHORT)
    env.reset(seed=0)
    kappas = [env.step(a)[4]["kappa"] for a in (3, np.int64(3), np.array(3), np.array([3]), 3.0)]
    assert kappas == [float(env.actions.kappas[3])] * 5


@pytest.mark.parametrize("bad", [np.array([np.nan]), np.array([1.5]), np.array([0.1, 0.2])])
def test_invalid_continuous_action_raises(bad: np.ndarray) -> None:
    env = TransferAlignmentEnv(action_type="continuous", overrides=SHORT)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="continuous action"):
        env.step(bad)


def test_continuous_action_maps_to_log_kappa() -> None:
    env = TransferAlignmentEnv(action_type="continuous", overrides=SHORT)
    env.reset(seed=0)
    for u, kappa in [(-1.0, 0.01), (0.0, 1.0), (1.0, 100.0)]:
        info = env.step(np.array([u], dtype=np.float32))[4]
        assert info["kappa"] == pytest.approx(kappa)


def test_divergence_ends_the_episode() -> None:
    env = TransferAlignmentEnv(overrides=SHORT)
    env.reset(seed=0)
    env._driver.core.gyro[0, 25] = np.nan  # a broken sensor sample in the third period
    for _ in range(2):
        assert env.step(5)[2] is False
    obs, reward, terminated, truncated, info = env.step(5)
    assert terminated and not truncated and info["diverged"]
    assert np.all(np.isfinite(obs)) and reward < 0


def test_step_before_reset_is_an_error() -> None:
    with pytest.raises(RuntimeError, match="reset"):
        TransferAlignmentEnv(overrides=SHORT).step(0)


def test_module_exports() -> None:
    assert envs.ENV_ID == ENV_ID


def test_episode_length_follows_the_config_for_make_and_make_vec() -> None:
    """A 7200-s scenario with a 20-s decision period: 360 steps in both front ends, the same
    rewards step for step, and truncation exactly at the end."""
    kw = {"overrides": ["scenario.duration_s=7200"], "period_s": 20.0}
    env = gym.make(ENV_ID, **kw)
    vec = gym.make_vec(ENV_ID, num_envs=1, vectorization_mode="vector_entry_point", **kw)
    env.reset(seed=5)
    vec.reset(seed=5)
    assert env.unwrapped.episode_steps == 360  # type: ignore[attr-defined]
    steps = 0
    while True:
        steps += 1
        _, r, term, trunc, _ = env.step(5)
        _, rv, tv, trv, _ = vec.step(np.array([5]))
        assert r == rv[0] and term == tv[0] and trunc == trv[0]
        if term or trunc:
            break
    assert steps == 360 and trunc and not term


def test_render_mode() -> None:
    assert gym.make(ENV_ID, render_mode=None, overrides=SHORT).render_mode is None
    with pytest.raises(ValueError, match="not supported"):
        TransferAlignmentEnv(render_mode="human", overrides=SHORT)


def test_a_registered_reward_is_usable_by_name() -> None:
    from envs import REWARDS, Reward

    def minus_nis(o):  # type: ignore[no-untyped-def]
        return -o.period_mean(np.nan_to_num(o.record.nis_att))

    if "test-minus-nis" not in REWARDS:
        REWARDS.register("test-minus-nis", Reward(minus_nis, "minus the attitude NIS"))
    env = TransferAlignmentEnv(reward="test-minus-nis", overrides=SHORT)
    env.reset(seed=0)
    _, r, *_ = env.step(5)
    assert r < 0.0
    with pytest.raises(ValueError, match="unknown reward 'nosuch'"):
        TransferAlignmentEnv(reward="nosuch", overrides=SHORT)


def test_randomized_family_as_scenario() -> None:
    """Episodes of thermal_snap_random differ in their schedule, and a seed repeats one."""
    env = TransferAlignmentEnv(scenario="thermal_snap_random")
    rates = []
    for seed in (1, 2, 1):
        env.reset(seed=seed)
        rates.append(np.linalg.norm(env._driver.core.gyro[0], axis=-1))
    np.testing.assert_array_equal(rates[0], rates[2])
    assert not np.array_equal(rates[0] > 0.2 * np.pi / 180, rates[1] > 0.2 * np.pi / 180)
