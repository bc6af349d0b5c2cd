"""Batched vector version of ``qkf/TransferAlignment-v0``: N episodes stepped at once through one
batched filter (not N environments in a loop). Gymnasium's ``VectorEnv`` API, next-step
autoreset; sub-environment ``i`` of ``reset(seed=s)`` is the single environment reset with
seed ``s + i``, step for step.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.core import OBS_LIMIT, OBS_SIZE, BatchedEpisodes, RewardKind
from envs.transfer_alignment import ActionMap, resolve_scenario
from qkf.config import Config


class TransferAlignmentVectorEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """N transfer-alignment episodes in one batched filter."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}  # noqa: RUF012

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: RewardKind = "likelihood",
        overrides: list[str] | None = None,
        **_: Any,
    ) -> None:
        if num_envs < 1:
            raise ValueError("num_envs must be at least 1")
        if reward not in ("likelihood", "oracle", "nees"):
            raise ValueError(f"reward must be likelihood, oracle or nees, not {reward!r}")
        self.num_envs = num_envs
        self.cfg = resolve_scenario(scenario, overrides)
        self.actions = ActionMap(np.asarray(self.cfg.adaptive.actions.values()), action_type)
        self.single_action_space = self.actions.space
        self.single_observation_space = spaces.Box(
            -OBS_LIMIT, OBS_LIMIT, shape=(OBS_SIZE,), dtype=np.float32
        )
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._core = BatchedEpisodes(self.cfg, num_envs, reward)
        self._rngs = [seeding.np_random()[0] for _ in range(num_envs)]
        self._needs_reset = np.ones(num_envs, dtype=bool)

    def _reset_env(self, i: int) -> np.ndarray:
        return self._core.reset(i, int(self._rngs[i].integers(2**63 - 1)))

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        seeds = (
            [seed + i for i in range(self.num_envs)]
            if isinstance(seed, int)
            else list(seed)
            if seed is not None
            else [None] * self.num_envs
        )
        if len(seeds) != self.num_envs:
            raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
        for i, s in enumerate(seeds):
            if s is not None or self._needs_reset[i]:
                self._rngs[i] = seeding.np_random(s)[0]
        obs = np.stack([self._reset_env(i) for i in range(self.num_envs)])
        self._needs_reset[:] = False
        return obs, {"kappa": np.ones(self.num_envs), "diverged": np.zeros(self.num_envs, bool)}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions)
        if actions.shape[0] != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions, got shape {actions.shape}")
        mapped = [self.actions(a) for a in actions]
        kappa = np.array([m[0] for m in mapped])
        pos = np.array([m[1] for m in mapped])
        out = self._core.step(kappa, pos)
        obs, reward = out.obs, out.reward
        term, trunc = out.terminated.copy(), out.truncated.copy()
        # next-step autoreset: episodes that ended on the previous step start over now
        for i in np.flatnonzero(self._needs_reset):
            obs[i] = self._reset_env(int(i))
            reward[i] = 0.0
            term[i] = trunc[i] = False
        self._needs_reset = term | trunc
        info = {
            "kappa": kappa,
            "diverged": out.terminated,
            "errors": out.errors,
            "crlb": out.crlb,
            "t_s": out.t_s,
        }
        return obs, reward, term, trunc, info
