"""What the batched Stable-Baselines3 adapters of the environments share
(:class:`envs.transfer_alignment.sb3.BatchedTransferAlignmentSB3Env`,
:class:`envs.redundant_gyros.sb3.BatchedGyroSB3Env`): SB3's ``VecEnv`` over a *driver* that
steps N episodes at once (:class:`~envs.common.driver.BatchedDriver`; sub-environment ``i``
seeded with ``s`` draws the episodes of the single environment reset with seed ``s + i``).

SB3's API is same-step autoreset: when an episode ends ``step_wait`` returns the first
observation of the next one and puts the last in ``info["terminal_observation"]`` (with
``info["TimeLimit.truncated"]`` and ``info["diverged"]``). Importing this module imports
Stable-Baselines3 (and torch), which ``import envs`` does not.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Generic

import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from envs.common.driver import DriverT


class BatchedSB3VecEnv(VecEnv, Generic[DriverT]):
    """SB3's ``VecEnv`` over a batched episode driver (module docstring), one sub-environment
    per episode of the driver. ``vector_actions``: the driver takes (N, D) actions (a
    continuous or multi-dimensional action space), else (N,)."""

    def __init__(self, driver: DriverT, vector_actions: bool) -> None:
        self._driver = driver
        self._vector_actions = vector_actions
        self.render_mode = None
        self.cfg = driver.cfg
        self.actions = driver.actions
        self.episode_steps = driver.episode_steps
        super().__init__(len(driver.rngs), driver.observation_space, driver.action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        for i, s in enumerate(self._seeds):
            if s is not None:
                self._driver.rngs[i] = seeding.np_random(s)[0]
        self._reset_seeds()
        return np.asarray(self._driver.reset_envs(np.arange(self.num_envs)))

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_async must come before step_wait")
        acts = self._actions.reshape(self.num_envs, -1)
        out = self._driver.step(acts if self._vector_actions else acts[:, 0])
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
            obs[ended] = self._driver.reset_envs(ended)
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
