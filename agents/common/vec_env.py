"""The vectorised environments of training, as Stable-Baselines3 ``VecEnv`` objects.

:func:`make_vec_env` builds the environment of a training config from the environment
registry (:data:`envs.ENVIRONMENTS`): the environment's own batched SB3 adapter where it has one
(all episodes in one batched filter), else SB3's ``DummyVecEnv`` over ``gym.make``. Nothing
here knows an environment by name. :class:`ScaledReward` multiplies the reward the learner sees
(``reward_scale``); RL Zoo3 uses it too (``agents/rl_zoo3/ppo.yml``).

``env_kwargs`` (keywords of the environment, ``ENVIRONMENTS[env].options``) go to its
constructor over the id's own keyword defaults (``spec.kwargs``); values the environment
refuses are a ``ConfigError`` naming ``env_kwargs``.

``frame_stack: k`` wraps the environment in SB3's ``VecFrameStack``: the policy sees its last
k observations side by side, oldest first, zeros before an episode's first
(:class:`agents.policy.Policy` stacks the same way when it acts on the benchmark's trials).

Seeding: sub-environment ``i`` of ``make_vec_env(cfg, n, seed)`` draws its episodes as the
single environment reset with seed ``seed + i`` (docs/environment.md, "Seeding").
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    VecEnv,
    VecEnvWrapper,
    VecFrameStack,
    VecMonitor,
)

from envs import ENVIRONMENTS
from qkf.core.config import ConfigError
from qkf.core.registry import load_object

if TYPE_CHECKING:
    from agents.config import TrainConfig


def make_vec_env(cfg: TrainConfig, n_envs: int, seed: int) -> VecEnv:
    """``n_envs`` episodes of the config's environment, seeded ``seed + i``."""
    spec = ENVIRONMENTS[cfg.env]
    kwargs: dict[str, Any] = {
        "scenario": cfg.scenario,
        "action_type": cfg.action_type,
        "reward": cfg.reward,
        "overrides": list(cfg.overrides),
        "period_s": cfg.period_s,
    }
    env: VecEnv
    try:
        if spec.sb3_vec_env is not None:  # one batched filter for all episodes
            # the id's own arguments, the config's env_kwargs over its keyword defaults
            options = {**kwargs, **spec.kwargs, **cfg.env_kwargs}
            env = load_object(spec.sb3_vec_env)(n_envs, **options)
        else:  # one environment per episode; gym.make adds the id's own arguments under ours
            import gymnasium as gym

            kwargs.update(cfg.env_kwargs)
            env = DummyVecEnv([lambda: gym.make(cfg.env, **kwargs) for _ in range(n_envs)])
    except (TypeError, ValueError) as exc:
        if not cfg.env_kwargs:  # the rest of the config was checked when it was loaded
            raise
        # the values of env_kwargs: only the environment itself can judge them
        msg = " ".join(str(exc).split()) or type(exc).__name__
        raise ConfigError(
            f"invalid training config\n  env_kwargs: {cfg.env} refuses "
            f"{json.dumps(cfg.env_kwargs, default=str)}: {msg}"
        ) from None
    env.seed(seed)
    if cfg.frame_stack > 1:  # the policy sees its last k observations, oldest first
        env = VecFrameStack(env, cfg.frame_stack)
    return env


def learner_env(cfg: TrainConfig, seed: int) -> VecEnv:
    """The environment the learner trains on: ``n_envs`` episodes seeded ``seed + i``, under
    SB3's episode statistics (returns, lengths, for TensorBoard) and, where the config asks,
    the learner's reward scale and clip (:class:`ScaledReward`)."""
    env: VecEnv = VecMonitor(make_vec_env(cfg, cfg.n_envs, seed))
    if cfg.reward_scale != 1.0 or cfg.reward_clip is not None:
        env = ScaledReward(env, cfg.reward_scale, cfg.reward_clip)
    return env


class ScaledReward(VecEnvWrapper):
    """Rewards times a constant for the learner (``reward_scale``), then clipped to
    ``±clip`` (``reward_clip``, if set); the monitor beneath and the evaluations see the reward
    as defined. A fixed factor and bound keep training deterministic and resumable, unlike
    running reward normalisation. The bound is for heavy-tailed rewards: one episode whose
    relative reward is −60 otherwise decides a whole batch's normalised advantages."""

    def __init__(self, venv: VecEnv, scale: float, clip: float | None = None) -> None:
        super().__init__(venv)
        self.scale = scale
        self.clip = clip

    def reset(self) -> Any:
        return self.venv.reset()

    def step_wait(self) -> Any:
        obs, reward, done, infos = self.venv.step_wait()
        reward = reward * self.scale
        if self.clip is not None:
            reward = np.clip(reward, -self.clip, self.clip)
        return obs, reward, done, infos
