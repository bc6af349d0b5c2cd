"""What the single environments share
(:class:`envs.transfer_alignment.env.TransferAlignmentEnv`,
:class:`envs.redundant_gyros.env.RedundantGyroCalibrationEnv`): Gymnasium's ``Env`` over
episode 0 of a driver of one episode (:class:`~envs.common.driver.BatchedDriver`), the same
episodes the batched front ends step, seeded through ``np_random``.

``render_mode="rgb_array"``: each step records into an :class:`~envs.common.render.EpisodeTrace`,
drawn only by ``render()``. A subclass runs the period (:meth:`SingleEpisodeEnv.run_period`: the
action mapped onto the driver), says what a step records and adds its own ``info`` entries
(:class:`~envs.common.driver.EpisodeHooks`).
"""

from __future__ import annotations

from typing import Any, Generic

import gymnasium as gym
import numpy as np

from envs.common.driver import DriverT, EpisodeHooks
from envs.common.render import RENDER_FPS, RENDER_MODES, EpisodeTrace


class SingleEpisodeEnv(gym.Env[np.ndarray, Any], EpisodeHooks, Generic[DriverT]):
    """One episode of ``driver`` as a Gymnasium ``Env`` (module docstring). ``trace``: the
    empty frame of an episode; ``render_mode``: checked by the subclass before it builds the
    driver (:func:`~envs.common.render.check_render_mode`)."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": RENDER_FPS}  # noqa: RUF012

    def __init__(self, driver: DriverT, trace: EpisodeTrace, render_mode: str | None) -> None:
        self._driver = driver
        self.render_mode = render_mode
        self.cfg = driver.cfg
        self.actions = driver.actions
        self.episode_steps = driver.episode_steps
        self.action_space = driver.action_space
        self.observation_space = driver.observation_space
        self._trace = trace
        self._started = False

    def run_period(self, action: Any) -> Any:
        """Run one decision period of the episode with ``action``; the driver's step output
        (one row)."""
        raise NotImplementedError

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._driver.rngs[0] = self.np_random
        obs = self._driver.reset_envs(np.array([0]))[0]
        self._started = True
        self._trace.clear()
        return obs, {"kappa": 1.0, "diverged": False, **self.reset_info()}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        out = self.run_period(action)
        kappa = float(out.kappa[0])
        info = {
            "kappa": kappa,
            "diverged": bool(out.terminated[0]),
            "errors": out.errors[0],
            **self.step_info(out),
        }
        if self.render_mode is not None:  # record only what render() will draw
            self._trace.append(float(out.t_s[0]), kappa, list(self.curves(out)[0]))
        return (
            out.obs[0],
            float(out.reward[0]),
            bool(out.terminated[0]),
            bool(out.truncated[0]),
            info,
        )

    def render(self) -> np.ndarray | None:
        """``render_mode="rgb_array"``: the episode so far as an RGB frame, ``(H, W, 3)`` uint8;
        ``None`` without a render mode."""
        return self._trace.frame() if self.render_mode is not None else None
