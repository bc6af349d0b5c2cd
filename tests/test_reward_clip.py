"""``reward_scale`` and ``reward_clip``: what the learner sees of the reward (the monitor and
the evaluations see it as defined)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from agents.common.vec_env import ScaledReward
from agents.config import TrainConfig


class _Rewards(gym.Env[np.ndarray, int]):
    """Rewards −50, 0.01, 3 in turn."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Discrete(2)

    def reset(self, *, seed=None, options=None):  # type: ignore[no-untyped-def]
        self.k = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):  # type: ignore[no-untyped-def]
        r = (-50.0, 0.01, 3.0)[self.k % 3]
        self.k += 1
        return np.zeros(1, np.float32), r, False, self.k >= 3, {}


@pytest.mark.parametrize("clip", [None, 0.5])
def test_rewards_are_scaled_then_clipped(clip: float | None) -> None:
    env = ScaledReward(DummyVecEnv([_Rewards]), 20.0, clip)
    env.reset()
    seen = [float(env.step(np.array([0]))[1][0]) for _ in range(3)]
    want = np.array([-1000.0, 0.2, 60.0])
    np.testing.assert_allclose(seen, want if clip is None else np.clip(want, -clip, clip))


def test_reward_clip_must_be_positive() -> None:
    with pytest.raises(ValueError):
        TrainConfig(agent="ppo", reward_clip=0.0)
    assert TrainConfig(agent="ppo").reward_clip is None
