r"""Gymnasium environments ``qkf/TransferAlignment-v0``, ``-v1``, ``-v2`` (docs/environment.md).

One episode is one realisation of a scenario (truth and noise drawn from ``np_random`` at
reset); one step is one decision period (``period_s``, 10 s by default) in which the
transfer-alignment filter runs with the process-noise factor κ the agent chose. An episode has
``ceil(duration / period)`` steps, from the config (``env.unwrapped.episode_steps``); the
environment truncates itself there, so ``gym.make`` and ``gym.make_vec`` agree for any duration.

Arguments: ``scenario`` (preset name, config path or ``Config``), ``action_type``
(``discrete`` | ``continuous``), ``reward`` (a name of
:data:`~envs.transfer_alignment.rewards.REWARDS`), ``overrides`` (``--set`` style),
``period_s``, ``observation`` (``v0`` … ``v2``, a name of
:data:`~envs.transfer_alignment.observations.OBSERVATIONS`, fixed by the registered id),
``render_mode`` (``None`` or ``"rgb_array"``: :meth:`~TransferAlignmentEnv.render` returns a
frame of the episode so far, below), ``data`` (recorded runs, a CSV/Parquet file, a folder or a
list: each episode replays one file, picked by the episode's generator, instead of a simulated
draw; ``scenario`` then supplies the noise, prior and filter settings and the data the step and
duration; docs/recorded_data.md).

Replay without truth columns: the reward is 0 and ``info["reward_available"]`` is False (it is
True otherwise); ``info["errors"]`` and ``info["crlb"]`` are NaN; a diverged filter still ends
the episode. With truth the rewards are those of a simulated episode (the CRLB is the config's
simulated trajectory's). ``info["file"]`` names the file replayed.

=====================  ===================================================================
Action                 Meaning
=====================  ===================================================================
``Discrete(A)``        index into the κ action set (default 11 values, 0.01 … 100)
``Box(-1, 1, (1,))``   ``action_type="continuous"``: linear in ``log10 κ`` over the set's range
=====================  ===================================================================

The observation of v0 (v1 and v2: :mod:`envs.transfer_alignment.observations`):

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

Rewards: see :mod:`envs.transfer_alignment.rewards`. ``info`` carries the true errors at the
end of the period in display units (``errors``: 15 values, the ``crlb.csv`` column order), the
CRLB there (``crlb``), ``kappa``, ``t_s`` and ``diverged``. A filter that goes non-finite ends
the episode (``terminated=True``).

Rendering: with ``render_mode="rgb_array"`` each step records four numbers (κ, and the RMS over
the nine calibration terms of the filter's σ, of the true error and of the CRLB, ppm and µrad);
``render()`` draws them into a small RGB frame (``FRAME_HEIGHT_PX × FRAME_WIDTH_PX × 3`` uint8)
and nothing is drawn in ``step`` (:mod:`envs.common.render`). ``render_mode=None`` (the
default) records nothing and ``render()`` returns ``None``. Stable-Baselines3's
``make_vec_env`` asks for ``"rgb_array"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from envs.common.render import RENDER_FPS, RENDER_MODES, EpisodeTrace, check_render_mode
from envs.transfer_alignment.episodes import DEFAULT_PERIOD_S, EpisodeDriver, StepOutput
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.states import DISPLAY_UNIT

CALIBRATION = slice(6, 15)
"""The nine calibration states (scale factors, misalignments) in the 15-value error state."""


def calibration_rms(values: np.ndarray) -> np.ndarray:
    """RMS over the nine calibration terms of display-unit state values (last axis 15): ppm and
    µrad are both 1e-6, so the mixed RMS is meaningful in "ppm/µrad"."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged filter: inf/NaN, drawn as gaps
        return np.sqrt(np.mean(np.square(values[..., CALIBRATION]), axis=-1))


class TransferAlignmentEnv(gym.Env[np.ndarray, Any]):
    """Choose the filter's process-noise factor every decision period (see module docstring)."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": RENDER_FPS}  # noqa: RUF012

    def __init__(
        self,
        scenario: str | Path | Config = "paper",
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        render_mode: str | None = None,
        data: str | Path | Sequence[str | Path] | None = None,
        controls: str | None = None,
        base: str | None = None,
        expert: str | None = None,
    ) -> None:
        check_render_mode(render_mode)
        self.render_mode = render_mode
        self._driver = EpisodeDriver(
            1, scenario, action_type, reward, overrides, period_s, observation, data,
            controls, base, expert,
        )  # fmt: skip
        self.episode_steps = self._driver.episode_steps
        self.cfg = self._driver.cfg
        self.actions = self._driver.actions
        self.controls = self._driver.controls
        self.action_space = self._driver.action_space
        self.observation_space = self._driver.observation_space
        self._started = False
        self._trace = calibration_trace(self._driver, f"TransferAlignment ({observation})")

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._driver.rngs[0] = self.np_random
        obs = self._driver.reset_env(0)
        self._started = True
        self._trace.clear()
        return obs, {"kappa": 1.0, "diverged": False, **self._data_info()}

    def _data_info(self) -> dict[str, Any]:
        """``reward_available`` (False: recorded data without truth, the reward is 0) and, on
        recorded data, the ``file`` the episode replays."""
        core = self._driver.core
        info: dict[str, Any] = {"reward_available": core.reward_available}
        if core.recorded is not None:
            info["file"] = str(core.recorded.files[int(core.file_index[0])].path)
        return info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if self.controls is not None:  # v4: the moves of the controls
            out = self._driver.step(np.asarray(action)[None])
            kappa = float(out.kappa[0])
        else:
            kappa, position = self.actions(action)
            out = self._driver.core.step(np.array([kappa]), np.array([position]))
        info = {
            "kappa": kappa,
            "diverged": bool(out.terminated[0]),
            "errors": out.errors[0],
            "crlb": out.crlb[0],
            "t_s": float(out.t_s[0]),
            **self._data_info(),
            **_moves_info(out, 0),
        }
        if self.render_mode is not None:  # record only what render() will draw
            self._trace.append(info["t_s"], kappa, calibration_curves(self._driver, out)[0])
        return (
            out.obs[0],
            float(out.reward[0]),
            bool(out.terminated[0]),
            bool(out.truncated[0]),
            info,
        )

    def expert_actions(self) -> np.ndarray:
        """The expert's action for the next step (``expert=``, v4; an array of the action
        space's shape)."""
        return self._driver.expert_actions()[0]

    def render(self) -> np.ndarray | None:
        """``render_mode="rgb_array"``: the episode so far as an RGB frame, ``(H, W, 3)`` uint8
        (κ chosen per step; the calibration σ of the filter, the true error and the CRLB).
        ``None`` without a render mode."""
        return self._trace.frame() if self.render_mode is not None else None


def _moves_info(out: StepOutput, row: int) -> dict[str, Any]:
    """v4's ``info`` entries of episode ``row``: the moves of the step (none without
    controls)."""
    if out.moves is None:
        return {}
    m = out.moves
    return {
        "q_att": float(m.q_att[row]),
        "q_bias": float(m.q_bias[row]),
        "r_scale": float(m.r_scale[row]),
        "reset": float(m.reset[row]),
    }


CALIBRATION_CURVES = ("filter σ", "true error", "CRLB")
"""The curves of the transfer-alignment frames, all RMS over the nine calibration terms."""


def calibration_trace(driver: EpisodeDriver, title: str) -> EpisodeTrace:
    """The (empty) trace of one transfer-alignment episode of ``driver``'s config."""
    kappas = driver.actions.kappas
    return EpisodeTrace(
        title,
        CALIBRATION_CURVES,
        "calibration RMS [ppm, µrad]",
        (float(kappas.min()), float(kappas.max())),
        (0.0, float(driver.core.t[-1])),
    )


def calibration_curves(driver: EpisodeDriver, out: StepOutput) -> np.ndarray:
    """Every episode's filter σ, true error and CRLB after a step, ``(N, 3)``: RMS over the
    calibration terms, ppm/µrad. The σ is read from the filters' covariance (N × 15 × 15)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged filter: inf/NaN → gaps
        # |diag| only so that a broken (negative) variance of a diverged filter draws, not warns
        var = np.abs(np.diagonal(driver.core.kf.P, axis1=1, axis2=2))
        sigma = np.sqrt(var) / DISPLAY_UNIT
    return np.stack(
        [calibration_rms(sigma), calibration_rms(out.errors), calibration_rms(out.crlb)], axis=1
    )
