"""The batched redundant-gyro environment as a Stable-Baselines3 ``VecEnv``.

The same batched episodes as :class:`envs.redundant_gyros.vector.BatchedGyroCalibrationEnv`,
with SB3's API: same-step autoreset, so when an episode ends ``step_wait`` returns the first
observation of the next episode and puts the last one in ``info["terminal_observation"]``
(with ``info["TimeLimit.truncated"]``). Sub-environment ``i`` seeded with ``s`` draws the same
episodes as ``RedundantGyroCalibrationEnv`` reset with seed ``s + i``. What ``qkf train``
trains on for these ids (``envs.ENVIRONMENTS[id].sb3_vec_env``). Importing this module imports
Stable-Baselines3 (and torch), which ``import envs`` does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from envs.redundant_gyros.env import DEFAULT_SCENARIOS
from envs.redundant_gyros.episodes import GyroEpisodes
from qkf.redundant_gyros.config import GyrosConfig


class BatchedGyroSB3Env(VecEnv):
    """N gyro-calibration episodes in one batched compiled UKF, as an SB3 ``VecEnv``."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | GyrosConfig | None = None,
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str | None = None,
        overrides: list[str] | None = None,
        period_s: float | None = None,
        observation: str = "v0",
    ) -> None:
        if scenario is None:
            scenario = DEFAULT_SCENARIOS.get(observation, DEFAULT_SCENARIOS["v0"])
        self.episodes = GyroEpisodes(
            num_envs, scenario, action_type, reward, overrides, period_s, observation
        )
        self.cfg = self.episodes.cfg
        self.actions = self.episodes.actions
        self.render_mode = None
        super().__init__(num_envs, self.episodes.observation_space, self.episodes.action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        for i, s in enumerate(self._seeds):
            if s is not None:
                self.episodes.rngs[i] = seeding.np_random(s)[0]
        self._reset_seeds()
        return self.episodes.reset_envs(np.arange(self.num_envs))

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_async must come before step_wait")
        acts = self._actions.reshape(self.num_envs, -1)
        out = self.episodes.step(acts if self.actions.action_type == "continuous" else acts[:, 0])
        obs = out.obs.copy()
        dones = out.terminated | out.truncated
        infos: list[dict[str, Any]] = []
        for i in range(self.num_envs):
            info: dict[str, Any] = {"kappa": out.kappa[i], "errors": out.errors[i]}
            if dones[i]:
                info["terminal_observation"] = out.obs[i]
                info["TimeLimit.truncated"] = bool(out.truncated[i])
                info["diverged"] = bool(out.terminated[i])
            infos.append(info)
        ended = np.flatnonzero(dones)
        if ended.size:  # the episodes that ended start over, together
            obs[ended] = self.episodes.reset_envs(ended)
        return obs, out.reward.astype(np.float32), dones, infos

    def close(self) -> None:
        return None

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **kwargs: Any
    ) -> list[Any]:
        raise NotImplementedError("the sub-environments are rows of one batch, not objects")

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs
