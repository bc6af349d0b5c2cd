r"""Gymnasium environments ``qkf/RedundantGyroCalibration-v0`` and ``-v1``
(docs/redundant_gyros.md, "Environment").

The adaptive-filter question of the transfer-alignment environment, on the redundant-gyro
problem: the UKF calibrates one isolated gyro's ``[b, λ, δ_u, δ_v]`` and the agent chooses the
factor κ on its process noise every decision period. One episode is one realisation of the
config's scenario (noise — and, with ``scenario.onset``, the onset time, step and drift — drawn
from ``np_random`` at reset); the calibrated gyro is ``calibration.gyro``, the first fault's
gyro or the onset's gyro, from ``calibration.start_s``, that fault's time or the start of the
run on (the FDI's choice is not the agent's question; a drawn onset is unknown to the filter).
One step is one decision period (``period_s``, default ``environment.period_s``); an episode
has ``ceil(K / period)`` steps, K the calibrated epochs — fixed by the config
(``env.unwrapped.episode_steps``).

Versions (``observation``, a name of
:data:`~envs.redundant_gyros.observations.GYRO_OBSERVATIONS`): ``"v0"``
(``qkf/RedundantGyroCalibration-v0``, default scenario ``five_gyros_s_bias``: a bias step at a
known time, constant coefficients otherwise), ``"v1"`` (``qkf/RedundantGyroCalibration-v1``,
default scenario ``five_gyros_onset_drift``: an onset drawn per episode with a step and a
random walk of the coefficients; its observation has no elapsed-time entry, so a policy reacts
to the evidence, not to the clock) and ``"v2"`` (``qkf/RedundantGyroCalibration-v2``, below).

Arguments: ``scenario`` (gyro preset name, config path or ``GyrosConfig``; ``None``: the
version's default), ``action_type`` (``discrete`` | ``continuous``), ``reward`` (a name of
:data:`~envs.redundant_gyros.rewards.GYRO_REWARDS`; ``None``: ``likelihood``, or ``oracle``
for v2), ``overrides``
(``--set`` style), ``period_s``, ``observation`` (``"v0"`` … ``"v4"``), ``render_mode``
(``None`` or ``"rgb_array"``, as the transfer-alignment environment: ``render()`` draws the κ
chosen so far and, over the four calibrated states, the RMS of the UKF's σ and of the true
error, both over the prior σ₀).

=====================  ===================================================================
Action                 Meaning
=====================  ===================================================================
``Discrete(A)``        index into ``environment.actions`` (default 11 κ, 0.01 … 100)
``Box(-1, 1, (1,))``   ``action_type="continuous"``: linear in ``log10 κ`` over that range
=====================  ===================================================================

Observation ``"v0"`` (9 entries):

=====  ==========================================================  ===========================
Obs    Meaning (float32; no truth)                                 Typical scale
=====  ==========================================================  ===========================
0      ``log10(σ_b / σ_b0)``, the UKF's bias sd over its prior sd   −4 … 0
1      same, λ                                                      −3 … 0
2      same, δ_u                                                    −5 … 0
3      same, δ_v                                                    −5 … 0
4      mean NIS ``ν² / S`` over the period                          ~1 (jumps at a fault)
5      log-likelihood gain over a κ = 1 copy, per step              −1 … 1
6      elapsed fraction of the episode                              0 … 1
7      ``|ω̂_H|`` of the healthy triad at the period's end, deg/s    0 … 6
8      κ position in [0, 1] on the action scale                     0 … 1
=====  ==========================================================  ===========================

Observation ``"v1"`` (8 entries): v0 without the elapsed fraction (entry 6), the later entries
moved up by one; the NIS (entry 4) jumps at the drawn onset.

Observation ``"v2"`` (7 entries: v1 without the likelihood gain, so no κ = 1 copy of the filter
runs): ``log10(σ/σ₀)`` of the four states, mean NIS, ``|ω̂_H|``, κ position.
Observation ``"v3"`` (``qkf/RedundantGyroCalibration-v3``, default scenario
``gyro_noise_levels``; 8 entries): v2 with the innovations' lag-1 correlation after the NIS.
Observation ``"v4"`` (``qkf/RedundantGyroCalibration-v4``, default scenario
``gyro_noise_levels``; 9 entries): v3 with ``log10 θ̂_R`` after the lag-1 entry, the
variational-Bayes estimate of the white noise's scale over the assumed that the ``vb-noise``
baseline reads (the table: :mod:`envs.redundant_gyros.observations`).

The filter is the compiled UKF (:mod:`qkf.redundant_gyros.ukf_compiled`, held to filterpy's at
1e-9 σ₀), stepped by :class:`~envs.redundant_gyros.episodes.GyroEpisodes` with one episode;
the batched twins over N episodes are :mod:`envs.redundant_gyros.vector` (Gymnasium) and
:mod:`envs.redundant_gyros.sb3` (Stable-Baselines3), the same episode for the same seed.

Rewards: :mod:`envs.redundant_gyros.rewards` (:data:`GYRO_REWARDS`, entry-point group
``qkf.gyro_rewards``). ``info`` carries the true errors at the period's end in display units
(``errors``: b deg/s, λ, δ_u deg, δ_v deg), ``kappa``, ``t_s``, ``gyro`` and ``diverged`` (and
``onset_s``, the drawn onset, in a scenario with one: truth, for evaluation only). A
filter that fails (non-finite, or a covariance that is not positive definite) ends the episode
(``terminated=True``, reward −1000).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from envs.common.render import EpisodeTrace, check_render_mode
from envs.common.single import SingleEpisodeEnv
from envs.redundant_gyros.episodes import GyroEpisodes, GyroStep
from envs.redundant_gyros.observations import GYRO_OBSERVATIONS
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.ukf import DISPLAY_SCALE

OBS_SIZES = {name: GYRO_OBSERVATIONS[name].size for name in GYRO_OBSERVATIONS}
"""Entries of the observation of each version."""
OBS_SIZE = OBS_SIZES["v0"]
"""Entries of the v0 observation (table above)."""
GYRO_CURVES = ("UKF σ / σ₀", "|error| / σ₀")
"""The curves of the rendered frames: RMS over ``[b, λ, δ_u, δ_v]``, each over its prior sd."""


def gyro_trace(episodes: GyroEpisodes, title: str) -> EpisodeTrace:
    """The (empty) trace of one gyro episode of ``episodes``' config."""
    kappas = episodes.actions.kappas
    t = episodes.t
    return EpisodeTrace(
        title,
        GYRO_CURVES,
        "RMS over the prior σ₀",
        (float(kappas.min()), float(kappas.max())),
        (float(t[episodes.target.start]), float(t[-1])),  # the calibrated span
    )


def gyro_curves(episodes: GyroEpisodes, errors: np.ndarray) -> np.ndarray:
    """Every episode's UKF σ and true error ``errors`` (N, 4, display units) after a step, RMS
    over the four states of each over its prior sd (N, 2), dimensionless."""
    p0 = episodes.setup.p0_sd
    with np.errstate(over="ignore", invalid="ignore"):  # a failed filter: inf/NaN → gaps
        # |diag| only so that a broken (negative) variance of a failed UKF draws, not warns
        sd = np.sqrt(np.abs(np.diagonal(episodes.p, axis1=1, axis2=2)))
        err = errors * DISPLAY_SCALE
        return np.stack(
            [
                np.sqrt(np.mean(np.square(sd / p0), axis=1)),
                np.sqrt(np.mean(np.square(err / p0), axis=1)),
            ],
            axis=1,
        )


class RedundantGyroCalibrationEnv(SingleEpisodeEnv[GyroEpisodes]):
    """Choose the calibration UKF's process-noise factor every period (module docstring)."""

    def __init__(
        self,
        scenario: str | Path | GyrosConfig | None = None,
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str | None = None,
        overrides: list[str] | None = None,
        period_s: float | None = None,
        render_mode: str | None = None,
        observation: str = "v0",
    ) -> None:
        check_render_mode(render_mode)
        self.episodes = ep = GyroEpisodes(
            1, scenario, action_type, reward, overrides, period_s, observation
        )
        self.observation = observation
        self.obs_size = OBS_SIZES[observation]
        self.unit, self.setup, self.t = ep.unit, ep.setup, ep.t
        self.target, self.period, self.n_steps = ep.target, ep.period, ep.n_steps
        self.reward = ep.reward
        self._gyro = self.unit.ids[self.setup.gyro]
        trace = gyro_trace(ep, f"RedundantGyroCalibration (gyro {self._gyro})")
        super().__init__(ep, trace, render_mode)

    def reset_info(self) -> dict[str, Any]:
        """The calibrated ``gyro`` and, in a scenario with one, the drawn ``onset_s``."""
        info: dict[str, Any] = {"gyro": self._gyro}
        onset = self.episodes.onset(0)
        if onset is not None:
            info["onset_s"] = onset
        return info

    def run_period(self, action: Any) -> GyroStep:
        kappa, position = self.actions(action)
        return self.episodes.run(np.array([kappa]), np.array([position]))

    def step_info(self, out: GyroStep) -> dict[str, Any]:
        """The time and the :meth:`reset_info` entries."""
        return {"t_s": float(out.t_s[0]), **self.reset_info()}

    def curves(self, out: GyroStep) -> np.ndarray:
        return gyro_curves(self.episodes, out.errors)
