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

Versions (``observation``): ``"v0"`` (``qkf/RedundantGyroCalibration-v0``, default scenario
``five_gyros_s_bias``: a bias step at a known time, constant coefficients otherwise) and
``"v1"`` (``qkf/RedundantGyroCalibration-v1``, default scenario ``five_gyros_onset_drift``: an
onset drawn per episode with a step and a random walk of the coefficients; its observation has
no elapsed-time entry, so a policy reacts to the evidence, not to the clock).

Arguments: ``scenario`` (gyro preset name, config path or ``GyrosConfig``; ``None``: the
version's default), ``action_type`` (``discrete`` | ``continuous``), ``reward`` (a name of
:data:`~envs.redundant_gyros.rewards.GYRO_REWARDS`), ``overrides``
(``--set`` style), ``period_s``, ``observation`` (``"v0"`` | ``"v1"``), ``render_mode``
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

Observation ``"v1"`` (8 entries: v0 without the elapsed fraction):

=====  ==========================================================  ===========================
Obs    Meaning (float32; no truth)                                 Typical scale
=====  ==========================================================  ===========================
0      ``log10(σ_b / σ_b0)``, the UKF's bias sd over its prior sd   −4 … 0
1      same, λ                                                      −3 … 0
2      same, δ_u                                                    −5 … 0
3      same, δ_v                                                    −5 … 0
4      mean NIS ``ν² / S`` over the period                          ~1 (jumps at an onset)
5      log-likelihood gain over a κ = 1 copy, per step              −1 … 1
6      ``|ω̂_H|`` of the healthy triad at the period's end, deg/s    0 … 6
7      κ position in [0, 1] on the action scale                     0 … 1
=====  ==========================================================  ===========================

Rewards: :mod:`envs.redundant_gyros.rewards` (:data:`GYRO_REWARDS`, entry-point group
``qkf.gyro_rewards``). ``info`` carries the true errors at the period's end in display units
(``errors``: b deg/s, λ, δ_u deg, δ_v deg), ``kappa``, ``t_s``, ``gyro`` and ``diverged`` (and
``onset_s``, the drawn onset, in a scenario with one: truth, for evaluation only). A
filter that fails (non-finite, or a covariance that is not positive definite) ends the episode
(``terminated=True``, reward −1000).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

from envs.common.actions import ActionMap
from envs.common.bounds import DIVERGENCE_REWARD, finite_clipped, observation_box
from envs.common.render import RENDER_FPS, RENDER_MODES, EpisodeTrace, check_render_mode
from envs.redundant_gyros.rewards import GYRO_REWARDS, GyroPeriod
from qkf.redundant_gyros.config import GyrosConfig, load_config
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import episode_inputs, fault_target, setup_for
from qkf.redundant_gyros.scenario import epochs
from qkf.redundant_gyros.ukf import DISPLAY_SCALE, CalibrationUKF, log_likelihood

OBS_SIZE = 9
"""Entries of the v0 observation (table above)."""
OBS_SIZES = {"v0": OBS_SIZE, "v1": 8}
"""Entries of the observation of each version."""
DEFAULT_SCENARIOS = {"v0": "five_gyros_s_bias", "v1": "five_gyros_onset_drift"}
"""The scenario of each version when none is given."""
ELAPSED = 6
"""Index of the elapsed fraction in the v0 observation (v1 leaves it out)."""
GYRO_CURVES = ("UKF σ / σ₀", "|error| / σ₀")
"""The curves of the rendered frames: RMS over ``[b, λ, δ_u, δ_v]``, each over its prior sd."""


class RedundantGyroCalibrationEnv(gym.Env[np.ndarray, Any]):
    """Choose the calibration UKF's process-noise factor every period (module docstring)."""

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": RENDER_FPS}  # noqa: RUF012

    def __init__(
        self,
        scenario: str | Path | GyrosConfig | None = None,
        action_type: Literal["discrete", "continuous"] = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float | None = None,
        render_mode: str | None = None,
        observation: Literal["v0", "v1"] = "v0",
    ) -> None:
        check_render_mode(render_mode)
        if reward not in GYRO_REWARDS:
            raise ValueError(f"unknown reward {reward!r}; known: {', '.join(GYRO_REWARDS)}")
        if observation not in OBS_SIZES:
            raise ValueError(f"unknown observation {observation!r}; known: v0, v1")
        self.observation = observation
        self.obs_size = OBS_SIZES[observation]
        self.render_mode = render_mode
        if scenario is None:
            scenario = DEFAULT_SCENARIOS[observation]
        self.cfg = (
            scenario if isinstance(scenario, GyrosConfig) else load_config(scenario, overrides)
        )
        self.reward_name = reward
        self.reward = GYRO_REWARDS[reward]
        self.unit = build_unit(self.cfg)
        sc = self.cfg.scenario
        self.t = epochs(sc.duration_s, sc.dt_s)
        self.target = fault_target(self.cfg, self.unit, self.t)
        self.setup = setup_for(self.cfg, self.unit, self.target)
        period = self.cfg.environment.period_s if period_s is None else period_s
        if not (math.isfinite(period) and period > 0.0):
            raise ValueError(f"period_s must be positive, got {period!r}")
        self.period = max(1, round(period / sc.dt_s))
        self.n_steps = self.t.size - self.target.start  # calibrated epochs per episode
        self.episode_steps = math.ceil(self.n_steps / self.period)
        kappas = np.asarray(self.cfg.environment.actions.values())
        self.actions = ActionMap(kappas, action_type)
        self.action_space = self.actions.space
        self.observation_space = observation_box(self.obs_size)
        self._start_pos = self.cfg.environment.actions.nominal_index() / (kappas.size - 1)
        self._started = False
        self._trace = EpisodeTrace(
            f"RedundantGyroCalibration (gyro {self.unit.ids[self.setup.gyro]})",
            GYRO_CURVES,
            "RMS over the prior σ₀",
            (float(kappas.min()), float(kappas.max())),
            (float(self.t[self.target.start]), float(self.t[-1])),  # the calibrated span
        )

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        draw = int(self.np_random.integers(2**63 - 1))
        ep = episode_inputs(self.cfg, self.unit, self.setup, self.target, self.t, draw)
        self._z, self._rate, self._truth, self._dt = ep.z, ep.rate, ep.truth, ep.dt
        self._onset_s = ep.onset_s
        self._main = CalibrationUKF(self.setup, float(self._dt[0]))
        self._nominal = CalibrationUKF(self.setup, float(self._dt[0]))
        self._k = 0
        self._started = True
        self._trace.clear()
        obs = np.zeros(self.obs_size, dtype=np.float32)
        obs[-1] = self._start_pos
        info: dict[str, Any] = {
            "kappa": 1.0,
            "diverged": False,
            "gyro": self.unit.ids[self.setup.gyro],
        }
        if self._onset_s is not None:
            info["onset_s"] = self._onset_s
        return obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError("call reset() before step()")
        kappa, pos = self.actions(action)
        main, nominal = self._main, self._nominal
        nominal.load(main.x, main.P, main.diverged)
        k0, k1 = self._k, min(self._k + self.period, self.n_steps)
        nu, var, nu_nom, var_nom = (np.full(k1 - k0, np.nan) for _ in range(4))
        errors = np.full((k1 - k0, 4), np.nan)
        cov = np.full((k1 - k0, 4, 4), np.nan)
        for i, k in enumerate(range(k0, k1)):
            z, rate, dt = float(self._z[k]), self._rate[k], float(self._dt[k])
            res = main.step(z, rate, dt, kappa)
            if not res.ok:
                break
            nu[i], var[i] = res.innovation, res.variance
            errors[i], cov[i] = main.x - self._truth[k], main.P
            res_nom = nominal.step(z, rate, dt, 1.0)
            nu_nom[i], var_nom[i] = res_nom.innovation, res_nom.variance
        self._k = k1
        diverged = main.diverged
        info: dict[str, Any] = {
            "kappa": kappa,
            "diverged": diverged,
            "gyro": self.unit.ids[self.setup.gyro],
            "t_s": float(self.t[self.target.start + k1 - 1]),
            "errors": errors[-1] / DISPLAY_SCALE,
        }
        if self._onset_s is not None:
            info["onset_s"] = self._onset_s
        if self.render_mode is not None:  # record only what render() will draw
            self._trace.append(info["t_s"], kappa, self._render_values(errors[-1]))
        obs = np.zeros(self.obs_size, dtype=np.float32)
        if diverged:
            obs[-1] = pos
            return obs, DIVERGENCE_REWARD, True, False, info
        ll = float(np.sum(log_likelihood(nu, var)))
        # a κ = 1 copy that fails where the agent's filter does not: no gain either way
        ll_nom = ll if nominal.diverged else float(np.sum(log_likelihood(nu_nom, var_nom)))
        steps = k1 - k0
        period = GyroPeriod(ll - ll_nom, errors, cov, self.setup.p0_sd, steps, float(self._dt[k0]))
        reward = float(self.reward.fn(period))
        if not math.isfinite(reward):
            reward = DIVERGENCE_REWARD
        sd = np.sqrt(np.diag(main.P))
        values = [
            *np.log10(sd / self.setup.p0_sd),
            float(np.mean(nu**2 / var)),
            (ll - ll_nom) / steps,
            k1 / self.n_steps,
            float(np.linalg.norm(self._rate[k1 - 1])),
            pos,
        ]
        if self.observation != "v0":
            del values[ELAPSED]
        obs = finite_clipped(np.asarray(values))
        return obs, reward, False, k1 >= self.n_steps, info

    def _render_values(self, error: np.ndarray) -> list[float]:
        """The UKF's σ and the true error ``error`` (4,) at the period's end, RMS over the four
        states of each over its prior sd (dimensionless)."""
        p0 = self.setup.p0_sd
        with np.errstate(over="ignore", invalid="ignore"):  # a failed filter: inf/NaN → gaps
            # |diag| only so that a broken (negative) variance of a failed UKF draws, not warns
            sd = np.sqrt(np.abs(np.diag(self._main.P)))
            return [
                float(np.sqrt(np.mean(np.square(sd / p0)))),
                float(np.sqrt(np.mean(np.square(error / p0)))),
            ]

    def render(self) -> np.ndarray | None:
        """``render_mode="rgb_array"``: the episode so far as an RGB frame, ``(H, W, 3)`` uint8;
        ``None`` without a render mode."""
        return self._trace.frame() if self.render_mode is not None else None
