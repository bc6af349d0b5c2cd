r"""Gymnasium environment ``qkf/TransferAlignment-v0`` (docs/environment.md).

One episode is one realisation of a scenario (truth and noise drawn from ``np_random`` at
reset); one step is one decision period (``period_s``, 10 s by default) in which the
transfer-alignment filter runs with the process-noise factor κ the agent chose. An episode has
``ceil(duration / period)`` steps, from the config (``env.unwrapped.episode_steps``); the
environment truncates itself there, so ``gym.make`` and ``gym.make_vec`` agree for any duration.

Arguments: ``scenario`` (preset name, config path or ``Config``), ``action_type``
(``discrete`` | ``continuous``), ``reward`` (a name of :data:`envs.rewards.REWARDS`),
``overrides`` (``--set`` style), ``period_s``, ``render_mode`` (None only).

=====================  ===================================================================
Action                 Meaning
=====================  ===================================================================
``Discrete(A)``        index into the κ action set (default 11 values, 0.01 … 100)
``Box(-1, 1, (1,))``   ``action_type="continuous"``: linear in ``log10 κ`` over the set's range
=====================  ===================================================================

=====  ==========================================================  ===========================
Obs    Meaning (float32)                                           Typical scale
=====  ==========================================================  ===========================
0      mean ``log10(σ/σ₀)`` of the attitude block of P              −3 … 0
1      same, bias block                                             −3 … 0
2      same, calibration block                                      −3 … 0
3      mean attitude NIS over the period / 3                        ~1 (jumps at events)
4      mean rate NIS over the period / 3 (0 without rate matching)  ~1
5      log-likelihood gain over the κ = 1 filter, per epoch & row   1e-6 … 1e-4
6      elapsed fraction of the episode                              0 … 1
7      ``|ω̂|``, deg/s                                              0.06 … 1
8      κ index scaled to [0, 1]                                     0 … 1
=====  ==========================================================  ===========================

Rewards: see :mod:`envs.rewards`. ``info`` carries the true errors at the end of the period in
display units (``errors``: 15 values, the ``crlb.csv`` column order), the CRLB there
(``crlb``), ``kappa``, ``t_s`` and ``diverged``. A filter that goes non-finite ends the episode
(``terminated=True``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from envs.episodes import DEFAULT_PERIOD_S, EpisodeDriver
from qkf.transfer_alignment.config import Config


def check_render_mode(render_mode: str | None) -> None:
    """The environments draw nothing: only ``render_mode=None`` is accepted."""
    if render_mode is not None:
        raise ValueError(
            f"render_mode {render_mode!r} is not supported: these environments draw nothing"
        )


class TransferAlignmentEnv(gym.Env[np.ndarray, Any]):
    """Choose the filter's process-noise factor every decision period (see module docstring)."""

    metadata = {"render_modes": []}  # noqa: RUF012 - Gymnasium's convention

    def __init__(
        self,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        render_mode: str | None = None,
    ) -> None:
        check_render_mode(render_mode)
        self.render_mode = render_mode
        self._driver = EpisodeDriver(
            1, scenario, action_type, reward, overrides, period_s, observation
        )
        self.episode_steps = self._driver.episode_steps
        self.cfg = self._driver.cfg
        self.actions = self._driver.actions
        self.action_space = self.actions.space
        self.observation_space = self._driver.observation_space
        self._started = False

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._driver.rngs[0] = self.np_random
        obs = self._driver.reset_env(0)
        self._started = True
        return obs, {"kappa": 1.0, "diverged": False}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        kappa, _ = self.actions(action)
        out = self._driver.step([action])
        info = {
            "kappa": kappa,
            "diverged": bool(out.terminated[0]),
            "errors": out.errors[0],
            "crlb": out.crlb[0],
            "t_s": float(out.t_s[0]),
        }
        return (
            out.obs[0],
            float(out.reward[0]),
            bool(out.terminated[0]),
            bool(out.truncated[0]),
            info,
        )
