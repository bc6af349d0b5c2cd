"""The batched transfer-alignment environment: N episodes of ``qkf/TransferAlignment-v0``,
``-v1`` or ``-v2`` stepped at once through one batched filter (not N environments in a loop),
as Gymnasium's ``VectorEnv`` (next-step autoreset); what ``gym.make_vec`` returns for these ids.
Sub-environment ``i`` of ``reset(seed=s)`` is the single environment reset with seed ``s + i``,
step for step. Its Stable-Baselines3 twin, over the same batched episodes, is
:class:`envs.transfer_alignment.sb3.BatchedTransferAlignmentSB3Env`.

``render_mode``: ``None`` (default) or ``"rgb_array"``; with the latter every sub-environment
records its episode as the single environment does, and ``render()`` returns one frame per
sub-environment (a tuple of ``(H, W, 3)`` uint8 arrays, as Gymnasium's ``SyncVectorEnv``); a
sub-environment autoreset starts its frame anew.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.common.render import RENDER_FPS, RENDER_MODES, check_render_mode
from envs.transfer_alignment.env import calibration_curves, calibration_trace
from envs.transfer_alignment.episodes import DEFAULT_PERIOD_S, EpisodeDriver
from qkf.transfer_alignment.config import Config


class BatchedTransferAlignmentEnv(VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """N transfer-alignment episodes in one batched filter, as a Gymnasium ``VectorEnv``."""

    metadata = {  # noqa: RUF012 - Gymnasium's convention
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": list(RENDER_MODES),
        "render_fps": RENDER_FPS,
    }

    def __init__(
        self,
        num_envs: int,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        render_mode: str | None = None,
        controls: str | None = None,
        base: str | None = None,
        expert: str | None = None,
        **kwargs: Any,
    ) -> None:
        if kwargs.get("data") is not None:  # not silently a simulation instead
            raise ValueError(
                "the batched vector environment does not replay recorded data; use "
                "gym.make(id, data=...) per environment (e.g. in SubprocVecEnv)"
            )
        check_render_mode(render_mode)
        self.render_mode = render_mode
        self.num_envs = num_envs
        self._driver = EpisodeDriver(
            num_envs, scenario, action_type, reward, overrides, period_s, observation,
            controls=controls, base=base, expert=expert,
        )  # fmt: skip
        self.episode_steps = self._driver.episode_steps
        self.cfg = self._driver.cfg
        self.single_action_space = self._driver.action_space
        self.single_observation_space = self._driver.observation_space
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self._needs_reset = np.ones(num_envs, dtype=bool)
        self._traces = [
            calibration_trace(self._driver, f"TransferAlignment ({observation}) #{i}")
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
                self._driver.rngs[i] = seeding.np_random(s)[0]
        obs = self._driver.reset_envs(np.arange(self.num_envs))
        self._needs_reset[:] = False
        for trace in self._traces:
            trace.clear()
        return obs, {"kappa": np.ones(self.num_envs), "diverged": np.zeros(self.num_envs, bool)}

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
            curves = calibration_curves(self._driver, out)
            for row, trace in enumerate(self._traces):
                if self._needs_reset[row]:  # this step restarted the episode: a new frame
                    trace.clear()
                else:
                    trace.append(float(out.t_s[row]), float(out.kappa[row]), curves[row])
        self._needs_reset = term | trunc
        info = {
            "kappa": out.kappa,
            "diverged": out.terminated,
            "errors": out.errors,
            "crlb": out.crlb,
            "t_s": out.t_s,
        }
        return obs, reward, term, trunc, info

    def render(self) -> tuple[np.ndarray, ...] | None:
        """``render_mode="rgb_array"``: one frame per sub-environment, as the single
        environment's ``render()``; ``None`` without a render mode."""
        if self.render_mode is None:
            return None
        return tuple(trace.frame() for trace in self._traces)
