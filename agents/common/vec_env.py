"""Stable-Baselines3 ``VecEnv`` over the batched transfer-alignment episodes.

SB3 expects same-step autoreset: when an episode ends, ``step_wait`` returns the first
observation of the next episode and puts the last one in ``info["terminal_observation"]``
(with ``info["TimeLimit.truncated"]`` for the time limit). Sub-environment ``i`` seeded with
``s`` draws the same episodes as ``TransferAlignmentEnv`` reset with seed ``s + i``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from envs.core import OBS_LIMIT, OBS_SIZE, BatchedEpisodes, RewardKind
from envs.transfer_alignment import ActionMap, resolve_scenario
from qkf.config import Config


class TransferAlignmentVecEnv(VecEnv):
    """N episodes stepped at once through one batched filter, for SB3 algorithms."""

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: RewardKind = "likelihood",
        overrides: list[str] | None = None,
    ) -> None:
        cfg = resolve_scenario(scenario, overrides)
        self.actions = ActionMap(np.asarray(cfg.adaptive.actions.values()), action_type)
        obs_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(OBS_SIZE,), dtype=np.float32)
        self.render_mode = None
        super().__init__(num_envs, obs_space, self.actions.space)
        self.cfg = cfg
        self._core = BatchedEpisodes(cfg, num_envs, reward)
        self._rngs = [seeding.np_random()[0] for _ in range(num_envs)]
        self._actions: np.ndarray | None = None

    def _reset_env(self, i: int) -> np.ndarray:
        return self._core.reset(i, int(self._rngs[i].integers(2**63 - 1)))

    def reset(self) -> np.ndarray:
        for i, s in enumerate(self._seeds):
            if s is not None:
                self._rngs[i] = seeding.np_random(s)[0]
        self._reset_seeds()
        return np.stack([self._reset_env(i) for i in range(self.num_envs)])

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_async must come before step_wait")
        acts = self._actions.reshape(self.num_envs, -1)
        mapped = [
            self.actions(a if self.actions.action_type == "continuous" else a[0]) for a in acts
        ]
        out = self._core.step(np.array([m[0] for m in mapped]), np.array([m[1] for m in mapped]))
        obs = out.obs.copy()
        dones = out.terminated | out.truncated
        infos: list[dict[str, Any]] = []
        for i in range(self.num_envs):
            info: dict[str, Any] = {"kappa": out.kappa[i], "errors": out.errors[i]}
            if dones[i]:
                info["terminal_observation"] = out.obs[i]
                info["TimeLimit.truncated"] = bool(out.truncated[i])
                info["diverged"] = bool(out.terminated[i])
                obs[i] = self._reset_env(i)
            infos.append(info)
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
