"""N redundant-gyro calibration episodes stepped together through the compiled UKF: what the
single environment, the Gymnasium vector environment and the SB3 adapter share
(docs/redundant_gyros.md, "Environment").

One :class:`GyroEpisodes` is a :class:`~qkf.redundant_gyros.batched_ukf.BatchedUKF` (the
episodes' inputs, drawn by :class:`~qkf.redundant_gyros.episodes.EpisodeSampler`, each
filter's state and its position; a decision period of every episode in one compiled call,
parallel over episodes) with the environments' actions, observations and rewards. Episode ``i``
draws its simulation seed from its own generator ``rngs[i]``, so an episode is the same in a
batch of 64 as alone. The κ = 1 copy behind the likelihood gain runs only when the
observation or the reward reads it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from envs.common.actions import ActionMap
from envs.common.bounds import DIVERGENCE_REWARD, observation_box
from envs.redundant_gyros.observations import GYRO_OBSERVATIONS, GyroObservationInputs
from envs.redundant_gyros.rewards import GYRO_REWARDS, GyroPeriod
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.batched_ukf import BatchedUKF
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.ukf import DISPLAY_SCALE
from qkf.redundant_gyros.vb_noise import R_HALF_DOF, ScalePosterior, period_measurement_statistic

DEFAULT_SCENARIOS = {
    "v0": "five_gyros_s_bias",
    "v1": "five_gyros_onset_drift",
    "v2": "five_gyros_onset_drift",
    "v3": "gyro_noise_levels",
    "v4": "gyro_noise_levels",
}
"""The scenario of each observation version when none is given."""


@dataclass(frozen=True)
class GyroStep:
    """One decision period of N episodes (display units in ``errors``: b deg/s, λ, δ deg)."""

    obs: np.ndarray  # (N, size) float32
    reward: np.ndarray  # (N,)
    terminated: np.ndarray  # (N,) the filter failed
    truncated: np.ndarray  # (N,) the episode's last period
    kappa: np.ndarray  # (N,)
    errors: np.ndarray  # (N, 4) x̂ − x at the period's end, display units
    t_s: np.ndarray  # (N,) time of the run at the period's last epoch, s


class GyroOptions(TypedDict, total=False):
    """The keywords the batched front ends pass on to :class:`GyroEpisodes` (its defaults where
    one is left out): ``(num_envs, scenario, **options)``."""

    action_type: Literal["discrete", "continuous"]
    reward: str | None
    overrides: list[str] | None
    period_s: float | None
    observation: str


class GyroEpisodes(BatchedUKF):
    """N calibration episodes of one gyro config (module docstring): a
    :class:`~qkf.redundant_gyros.batched_ukf.BatchedUKF` with actions, observations and
    rewards.

    ``scenario``: a gyro preset name, a config path or a :class:`GyrosConfig` (with
    ``overrides``; None: the observation version's :data:`DEFAULT_SCENARIOS`); ``reward``: a
    name of :data:`GYRO_REWARDS` (None: ``likelihood`` where the observation reads the κ = 1
    copy, else ``oracle``); ``observation``: a name of :data:`GYRO_OBSERVATIONS`;
    ``period_s``: the decision period (default ``environment.period_s``).
    """

    def __init__(
        self,
        n: int,
        scenario: str | Path | GyrosConfig | None,
        action_type: str = "discrete",
        reward: str | None = None,
        overrides: list[str] | None = None,
        period_s: float | None = None,
        observation: str = "v0",
    ) -> None:
        if n < 1:
            raise ValueError("num_envs must be at least 1")
        if observation not in GYRO_OBSERVATIONS:
            known = ", ".join(GYRO_OBSERVATIONS)
            raise ValueError(f"unknown observation {observation!r}; known: {known}")
        if reward is None:  # the version's own: one that needs no κ = 1 copy where it has none
            reward = "likelihood" if GYRO_OBSERVATIONS[observation].uses_nominal else "oracle"
        if reward not in GYRO_REWARDS:
            raise ValueError(f"unknown reward {reward!r}; known: {', '.join(GYRO_REWARDS)}")
        self.observation_version = observation
        if scenario is None:
            scenario = DEFAULT_SCENARIOS.get(observation, DEFAULT_SCENARIOS["v0"])
        self.cfg = (
            scenario if isinstance(scenario, GyrosConfig) else load_config(scenario, overrides)
        )
        sampler = EpisodeSampler(self.cfg)
        self.unit, self.t, self.target = sampler.unit, sampler.t, sampler.target
        period = self.cfg.environment.period_s if period_s is None else period_s
        if not (np.isfinite(period) and period > 0.0):
            raise ValueError(f"period_s must be positive, got {period!r}")
        self.reward = GYRO_REWARDS[reward]
        steps = max(1, round(period / self.cfg.scenario.dt_s))
        self.observation = GYRO_OBSERVATIONS[observation]
        keep_cov = self.reward.uses_cov or self.observation.uses_noise_scale
        super().__init__(sampler, n, steps, keep_cov=keep_cov)
        self.episode_steps = -(-self.n_steps // self.period)
        self.actions = ActionMap(np.asarray(self.cfg.environment.actions.values()), action_type)
        self.action_space: spaces.Space[Any] = self.actions.space
        # θ̂_R of each episode so far (vb_noise: a prior worth one period at the assumed noise)
        self.noise_scale = ScalePosterior.prior(n, 1.0, float(self.period), R_HALF_DOF)
        self.observation_space = observation_box(self.observation.size)
        self.needs_nominal = self.observation.uses_nominal or self.reward.uses_nominal
        kappas = self.actions.kappas
        self.start_position = self.cfg.environment.actions.nominal_index() / (kappas.size - 1)
        self.rngs = [seeding.np_random()[0] for _ in range(n)]

    def reset_envs(self, rows: np.ndarray) -> np.ndarray:
        """Start episodes ``rows`` anew, each drawing its simulation seed from its own
        generator; their first observations (len(rows), size): zeros but the κ position."""
        rows = np.asarray(rows, dtype=np.int64)
        seeds = [int(self.rngs[i].integers(2**63 - 1)) for i in rows]
        for i, seed in zip(rows, seeds, strict=True):
            self.load(int(i), self.sampler.draw(seed))
        self.restart(rows)
        self.noise_scale.restart(rows, 1.0, float(self.period))
        obs = np.zeros((rows.size, self.observation.size), dtype=np.float32)
        obs[:, -1] = self.start_position
        return obs

    def step(self, actions: Any) -> GyroStep:
        """Map one action per episode to κ and run one decision period of every episode."""
        return self.run(*self.actions.many(actions))

    def run(self, kappa: np.ndarray, position: np.ndarray) -> GyroStep:
        """One decision period of every episode with ``kappa`` (N,) (at ``position`` (N,) on
        the action scale, for the observation)."""
        # the estimates before the period, for the VB R scale (vb_noise, no forgetting) of v4
        x_prev = self.x.copy() if self.observation.uses_noise_scale else None
        k0, steps = self.advance(kappa, self.needs_nominal)
        k1 = k0 + steps
        theta_r = np.full(self.n, np.nan)
        if x_prev is not None:
            before = self.noise_scale.estimate
            s_r = period_measurement_statistic(self, self.period_epochs(k0), x_prev, before)
            theta_r = self.noise_scale.update(s_r, 1.0)
        # an episode past its end (the vector env's autoreset steps it before restarting it, and
        # drops what this step says of it) runs no epoch: divide its zero sums by 1, not 0
        per_step = np.maximum(steps, 1)
        failed = self.failed.copy()
        rows = np.arange(self.n)
        nis, ll, ll_nom, error, error_sq, lag1 = self.sums.T
        # a κ = 1 copy that fails where the agent's filter does not: no gain either way
        gain = ll - np.where(self.nominal_failed, ll, ll_nom) if self.needs_nominal else None
        dt = self.sampler.dt[np.minimum(k0, self.n_steps - 1)]
        period = GyroPeriod(
            loglik_gain=np.full(self.n, np.nan) if gain is None else gain,
            errors=self.err,
            cov=self.cov if self.reward.uses_cov else None,
            prior_sd=self.setup.p0_sd,
            steps=steps,
            dt=dt,
            normalised_error=error / per_step,
            normalised_sq_error=error_sq / (4.0 * per_step),
        )
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            reward = np.asarray(self.reward.fn(period), dtype=float)
        reward = np.where(np.isfinite(reward) & ~failed, reward, DIVERGENCE_REWARD)
        last = np.maximum(k1 - 1, 0)
        inputs = GyroObservationInputs(
            p=self.p,
            prior_sd=self.setup.p0_sd,
            nis=nis / per_step,
            lag1=lag1 / np.maximum(steps - 1, 1),
            loglik_gain_per_step=np.full(self.n, np.nan) if gain is None else gain / per_step,
            elapsed=k1 / self.n_steps,
            rate_norm=np.linalg.norm(self.rate[rows, last], axis=1),
            position=np.asarray(position, dtype=float),
            noise_scale=theta_r,
        )
        obs = self.observation.build(inputs)
        obs[failed] = 0.0
        obs[failed, -1] = np.asarray(position, dtype=np.float32)[failed]
        return GyroStep(
            obs=obs,
            reward=reward,
            terminated=failed,
            truncated=(k1 >= self.n_steps) & ~failed,
            kappa=np.asarray(kappa, dtype=float),
            errors=self.err[rows, np.maximum(steps - 1, 0)] / DISPLAY_SCALE,
            t_s=self.t[self.target.start + last],
        )

    def onset(self, row: int) -> float | None:
        """The drawn onset of episode ``row`` (truth, for evaluation); None without one."""
        v = float(self.onset_s[row])
        return None if np.isnan(v) else v


__all__ = ["DEFAULT_SCENARIOS", "GyroEpisodes", "GyroOptions", "GyroStep"]
