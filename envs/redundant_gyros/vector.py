"""The batched redundant-gyro environment: N episodes of ``qkf/RedundantGyroCalibration-v*``
stepped at once through the compiled UKF (one call per period for all of them, parallel over
episodes), as Gymnasium's ``VectorEnv`` (next-step autoreset); what ``gym.make_vec`` returns
for these ids. Sub-environment ``i`` of ``reset(seed=s)`` is the single environment reset with
seed ``s + i``, step for step. Its Stable-Baselines3 twin over the same batched episodes is
:class:`envs.redundant_gyros.sb3.BatchedGyroSB3Env`.

``render_mode``: ``None`` (default) or ``"rgb_array"`` (one frame per sub-environment, as the
single environment's ``render()``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.common.render import RENDER_FPS, RENDER_MODES, check_render_mode
from envs.redundant_gyros.env import DEFAULT_SCENARIOS, gyro_curves, gyro_trace
from envs.redundant_gyros.episodes import GyroEpisodes
from qkf.redundant_gyros.config import GyrosConfig


class BatchedGyroCalibrationEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """N gyro-calibration episodes in one batched compiled UKF, as a Gymnasium ``VectorEnv``."""

    metadata = {  # noqa: RUF012 - Gymnasium's convention
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": list(RENDER_MODES),
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | GyrosConfig | None = None,
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str | None = None,
        overrides: list[str] | None = None,
        period_s: float | None = None,
        observation: str = "v0",
        render_mode: str | None = None,
    ) -> None:
        check_render_mode(render_mode)
        self.render_mode = render_mode
        self.num_envs = num_envs
        if scenario is None:
            scenario = DEFAULT_SCENARIOS.get(observation, DEFAULT_SCENARIOS["v0"])
        self.episodes = GyroEpisodes(
            num_envs, scenario, action_type, reward, overrides, period_s, observation
        )
        self.cfg = self.episodes.cfg
        self.episode_steps = self.episodes.episode_steps
        self.single_action_space = self.episodes.action_space
        self.single_observation_space = self.episodes.observation_space
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._needs_reset = np.ones(num_envs, dtype=bool)
        self._traces = [
            gyro_trace(self.episodes, f"RedundantGyroCalibration ({observation}) #{i}")
            for i in range(num_envs)
        ]

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
                self.episodes.rngs[i] = seeding.np_random(s)[0]
        obs = self.episodes.reset_envs(np.arange(self.num_envs))
        self._needs_reset[:] = False
        for trace in self._traces:
            trace.clear()
        return obs, {
            "kappa": np.ones(self.num_envs),
            "diverged": np.zeros(self.num_envs, bool),
            "onset_s": self.episodes.onset_s.copy(),
        }

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions)
        if actions.shape[0] != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions, got shape {actions.shape}")
        out = self.episodes.step(actions)
        obs, reward = out.obs, out.reward
        term, trunc = out.terminated.copy(), out.truncated.copy()
        # next-step autoreset: episodes that ended on the previous step start over now
        restart = np.flatnonzero(self._needs_reset)
        if restart.size:
            obs[restart] = self.episodes.reset_envs(restart)
            reward[restart] = 0.0
            term[restart] = trunc[restart] = False
        if self.render_mode is not None:  # record only what render() will draw
            curves = gyro_curves(self.episodes, out.errors)
            for row, trace in enumerate(self._traces):
                if self._needs_reset[row]:  # this step restarted the episode: a new frame
                    trace.clear()
                else:
                    trace.append(float(out.t_s[row]), float(out.kappa[row]), list(curves[row]))
        self._needs_reset = term | trunc
        info = {
            "kappa": out.kappa,
            "diverged": out.terminated,
            "errors": out.errors,
            "t_s": out.t_s,
            "onset_s": self.episodes.onset_s.copy(),
        }
        return obs, reward, term, trunc, info

    def render(self) -> tuple[np.ndarray, ...] | None:
        """``render_mode="rgb_array"``: one frame per sub-environment; ``None`` without."""
        if self.render_mode is None:
            return None
        return tuple(trace.frame() for trace in self._traces)
