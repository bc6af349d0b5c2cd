r"""Gymnasium environments ``qkf/TransferAlignment-v0``, ``-v1``, ``-v2`` (docs/environment.md).

One episode is one realisation of a scenario (truth and noise drawn from ``np_random`` at
reset); one step is one decision period (``period_s``, 10 s by default) in which the
transfer-alignment filter runs with the process-noise factor κ the agent chose. An episode has
``ceil(duration / period)`` steps, from the config (``env.unwrapped.episode_steps``); the
environment truncates itself there, so ``gym.make`` and ``gym.make_vec`` agree for any duration.

Arguments (``scenario`` positional, the others keywords; their defaults are
:class:`~envs.transfer_alignment.episodes.EpisodeDriver`'s): ``scenario`` (preset name, config
path or ``Config``), ``action_type`` (``discrete`` | ``continuous``), ``reward`` (a name of
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
from typing import Any, Unpack

import numpy as np

from envs.common.render import EpisodeTrace, check_render_mode
from envs.common.single import SingleEpisodeEnv
from envs.transfer_alignment.episodes import EpisodeDriver, EpisodeOptions, StepOutput
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.states import DISPLAY_UNIT

CALIBRATION = slice(6, 15)
"""The nine calibration states (scale factors, misalignments) in the 15-value error state."""


def calibration_rms(values: np.ndarray) -> np.ndarray:
    """RMS over the nine calibration terms of display-unit state values (last axis 15): ppm and
    µrad are both 1e-6, so the mixed RMS is meaningful in "ppm/µrad"."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged filter: inf/NaN, drawn as gaps
        return np.sqrt(np.mean(np.square(values[..., CALIBRATION]), axis=-1))


class TransferAlignmentEnv(SingleEpisodeEnv[EpisodeDriver]):
    """Choose the filter's process-noise factor every decision period (see module docstring)."""

    def __init__(
        self,
        scenario: str | Path | Config = "paper",
        *,
        render_mode: str | None = None,
        data: str | Path | Sequence[str | Path] | None = None,
        **options: Unpack[EpisodeOptions],
    ) -> None:
        check_render_mode(render_mode)
        driver = EpisodeDriver(1, scenario, data=data, **options)
        title = f"TransferAlignment ({driver.observation_version})"
        super().__init__(driver, calibration_trace(driver, title), render_mode)
        self.controls = driver.controls

    def reset_info(self) -> dict[str, Any]:
        return self._data_info()

    def _data_info(self) -> dict[str, Any]:
        """``reward_available`` (False: recorded data without truth, the reward is 0) and, on
        recorded data, the ``file`` the episode replays."""
        core = self._driver.core
        info: dict[str, Any] = {"reward_available": core.reward_available}
        if core.recorded is not None:
            info["file"] = str(core.recorded.files[int(core.file_index[0])].path)
        return info

    def run_period(self, action: Any) -> StepOutput:
        """One period with ``action``: κ, or v4's moves of the controls."""
        if self.controls is not None:
            return self._driver.step(np.asarray(action)[None])
        kappa, position = self.actions(action)
        return self._driver.core.step(np.array([kappa]), np.array([position]))

    def step_info(self, out: StepOutput) -> dict[str, Any]:
        """The CRLB, the time, the data entries and v4's moves."""
        return {
            "crlb": out.crlb[0],
            "t_s": float(out.t_s[0]),
            **self._data_info(),
            **_moves_info(out, 0),
        }

    def curves(self, out: StepOutput) -> np.ndarray:
        return calibration_curves(self._driver, out)

    def expert_actions(self) -> np.ndarray:
        """The expert's action for the next step (``expert=``, v4; an array of the action
        space's shape)."""
        return self._driver.expert_actions()[0]


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
