"""What the batched Gymnasium vector environments share
(:class:`envs.transfer_alignment.vector.BatchedTransferAlignmentEnv`,
:class:`envs.redundant_gyros.vector.BatchedGyroCalibrationEnv`): Gymnasium's ``VectorEnv`` over
a *driver* that steps N episodes at once (:class:`~envs.common.driver.BatchedDriver`), with
next-step autoreset. Sub-environment ``i`` of ``reset(seed=s)`` is the single environment reset
with seed ``s + i``, step for step.

``render_mode="rgb_array"``: every sub-environment records its episode as the single
environment does (one :class:`~envs.common.render.EpisodeTrace` each) and ``render()`` returns
one frame per sub-environment; an autoreset starts its frame anew. A subclass says what a step
records and adds its own ``info`` entries (:class:`~envs.common.driver.EpisodeHooks`).
"""

from __future__ import annotations

from typing import Any, Generic

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.common.driver import DriverT, EpisodeHooks
from envs.common.render import RENDER_FPS, RENDER_MODES, EpisodeTrace, check_render_mode


class BatchedVectorEnv(
    VectorEnv[np.ndarray, np.ndarray, np.ndarray], EpisodeHooks, Generic[DriverT]
):
    """Gymnasium's ``VectorEnv`` over a batched episode driver (module docstring); as many
    sub-environments as the driver has episodes."""

    metadata = {  # noqa: RUF012 - Gymnasium's convention
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": list(RENDER_MODES),
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self, driver: DriverT, traces: list[EpisodeTrace], render_mode: str | None
    ) -> None:
        check_render_mode(render_mode)
        self.render_mode = render_mode
        self.num_envs = num_envs = len(driver.rngs)
        self._driver = driver
        self.cfg = driver.cfg
        self.episode_steps = driver.episode_steps
        self.single_action_space = driver.action_space
        self.single_observation_space = driver.observation_space
        self.action_space = batch_space(driver.action_space, num_envs)
        self.observation_space = batch_space(driver.observation_space, num_envs)
        self._needs_reset = np.ones(num_envs, dtype=bool)
        self._traces = traces

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
                self._driver.rngs[i] = seeding.np_random(s)[0]
        obs = self._driver.reset_envs(np.arange(self.num_envs))
        self._needs_reset[:] = False
        for trace in self._traces:
            trace.clear()
        info = {"kappa": np.ones(self.num_envs), "diverged": np.zeros(self.num_envs, bool)}
        return obs, {**info, **self.reset_info()}

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions)
        if actions.shape[0] != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions, got shape {actions.shape}")
        out = self._driver.step(actions)
        obs, reward = out.obs, out.reward
        term, trunc = out.terminated.copy(), out.truncated.copy()
        # next-step autoreset: episodes that ended on the previous step start over now
        restart = np.flatnonzero(self._needs_reset)
        if restart.size:
            obs[restart] = self._driver.reset_envs(restart)
            reward[restart] = 0.0
            term[restart] = trunc[restart] = False
        if self.render_mode is not None:  # record only what render() will draw
            curves = self.curves(out)
            for row, trace in enumerate(self._traces):
                if self._needs_reset[row]:  # this step restarted the episode: a new frame
                    trace.clear()
                else:
                    trace.append(float(out.t_s[row]), float(out.kappa[row]), list(curves[row]))
        self._needs_reset = term | trunc
        info = {"kappa": out.kappa, "diverged": out.terminated, "errors": out.errors}
        return obs, reward, term, trunc, {**info, **self.step_info(out)}

    def render(self) -> tuple[np.ndarray, ...] | None:
        """``render_mode="rgb_array"``: one frame per sub-environment, as the single
        environment's ``render()``; ``None`` without a render mode."""
        if self.render_mode is None:
            return None
        return tuple(trace.frame() for trace in self._traces)
