"""N redundant-gyro calibration episodes stepped together through the compiled UKF: what the
single environment, the Gymnasium vector environment and the SB3 adapter share
(docs/redundant_gyros.md, "Environment").

One :class:`GyroEpisodes` holds the episodes' inputs (drawn by
:class:`~qkf.redundant_gyros.episodes.EpisodeSampler`), each filter's state and its position,
and runs a decision period of every episode in one call of
:func:`~qkf.redundant_gyros.ukf_compiled.run_periods` (parallel over episodes). Episode ``i``
draws its simulation seed from its own generator ``rngs[i]``, so an episode is the same in a
batch of 64 as alone. The κ = 1 copy behind the likelihood gain runs only when the
observation or the reward reads it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from envs.common.actions import ActionMap
from envs.common.bounds import DIVERGENCE_REWARD, observation_box
from envs.redundant_gyros.observations import GYRO_OBSERVATIONS, GyroObservationInputs
from envs.redundant_gyros.rewards import GYRO_REWARDS, GyroPeriod
from qkf.redundant_gyros.config import GyrosConfig, load_config
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.ukf import DISPLAY_SCALE
from qkf.redundant_gyros.ukf_compiled import SUMS, CompiledSetup, run_periods

DEFAULT_SCENARIOS = {
    "v0": "five_gyros_s_bias",
    "v1": "five_gyros_onset_drift",
    "v2": "five_gyros_onset_drift",
    "v3": "gyro_noise_levels",
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


class GyroEpisodes:
    """N calibration episodes of one gyro config (module docstring).

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
        if scenario is None:
            scenario = DEFAULT_SCENARIOS.get(observation, DEFAULT_SCENARIOS["v0"])
        self.cfg = (
            scenario if isinstance(scenario, GyrosConfig) else load_config(scenario, overrides)
        )
        self.sampler = sampler = EpisodeSampler(self.cfg)
        self.unit, self.setup, self.t = sampler.unit, sampler.setup, sampler.t
        self.target = sampler.target
        sc = self.cfg.scenario
        period = self.cfg.environment.period_s if period_s is None else period_s
        if not (np.isfinite(period) and period > 0.0):
            raise ValueError(f"period_s must be positive, got {period!r}")
        self.period = max(1, round(period / sc.dt_s))
        self.n, self.n_steps = n, sampler.n_epochs  # episodes, calibrated epochs per episode
        self.episode_steps = -(-self.n_steps // self.period)
        self.actions = ActionMap(np.asarray(self.cfg.environment.actions.values()), action_type)
        self.action_space: spaces.Space[Any] = self.actions.space
        self.observation = GYRO_OBSERVATIONS[observation]
        self.observation_space = observation_box(self.observation.size)
        self.reward = GYRO_REWARDS[reward]
        self.needs_nominal = self.observation.uses_nominal or self.reward.uses_nominal
        kappas = self.actions.kappas
        self.start_position = self.cfg.environment.actions.nominal_index() / (kappas.size - 1)
        self.compiled = CompiledSetup.of(self.setup)
        self.rngs = [seeding.np_random()[0] for _ in range(n)]
        k, p = self.n_steps, self.period
        self.z, self.rate = np.zeros((n, k)), np.zeros((n, k, 3))
        self.truth = np.zeros((n, k, 4))
        self.onset_s = np.full(n, np.nan)
        self.x, self.p = np.zeros((n, 4)), np.zeros((n, 4, 4))
        self.failed = np.zeros(n, dtype=bool)
        self.k = np.zeros(n, dtype=np.int64)  # next epoch of each episode
        self._inv_sd = 1.0 / self.setup.p0_sd
        self._sums = np.zeros((n, len(SUMS)))
        self._err = np.empty((n, p, 4))
        self._cov = np.empty((n, p, 4, 4) if self.reward.uses_cov else (n, 1, 4, 4))
        self._nominal_failed = np.zeros(n, dtype=bool)

    def reset_envs(self, rows: np.ndarray) -> np.ndarray:
        """Start episodes ``rows`` anew, each drawing its simulation seed from its own
        generator; their first observations (len(rows), size): zeros but the κ position."""
        rows = np.asarray(rows, dtype=np.int64)
        s = self.setup
        seeds = [int(self.rngs[i].integers(2**63 - 1)) for i in rows]
        for i, seed in zip(rows, seeds, strict=True):
            ep = self.sampler.draw(seed)
            self.z[i], self.rate[i], self.truth[i] = ep.z, ep.rate, ep.truth
            self.onset_s[i] = np.nan if ep.onset_s is None else ep.onset_s
        self.x[rows] = s.x0
        self.p[rows] = np.diag(s.p0_sd**2)
        self.failed[rows] = False
        self.k[rows] = 0
        obs = np.zeros((rows.size, self.observation.size), dtype=np.float32)
        obs[:, -1] = self.start_position
        return obs

    def step(self, actions: Any) -> GyroStep:
        """Map one action per episode to κ and run one decision period of every episode."""
        return self.run(*self.actions.many(actions))

    def run(self, kappa: np.ndarray, position: np.ndarray) -> GyroStep:
        """One decision period of every episode with ``kappa`` (N,) (at ``position`` (N,) on
        the action scale, for the observation)."""
        k0 = self.k.copy()
        k1 = np.minimum(k0 + self.period, self.n_steps)
        steps = k1 - k0
        # an episode past its end (the vector env's autoreset steps it before restarting it, and
        # drops what this step says of it) runs no epoch: divide its zero sums by 1, not 0
        per_step = np.maximum(steps, 1)
        c = self.compiled
        run_periods(
            self.x, self.p, self.z, self.rate, self.sampler.dt, self.truth, self._inv_sd,
            np.asarray(kappa, dtype=float), k0, k1, self.needs_nominal, self.reward.uses_cov,
            *c.geometry, c.weights, self.failed, self._nominal_failed, self._sums, self._err,
            self._cov,
        )  # fmt: skip
        self.k = k1
        failed = self.failed.copy()
        rows = np.arange(self.n)
        nis, ll, ll_nom, error, error_sq, lag1 = self._sums.T
        # a κ = 1 copy that fails where the agent's filter does not: no gain either way
        gain = ll - np.where(self._nominal_failed, ll, ll_nom) if self.needs_nominal else None
        dt = self.sampler.dt[np.minimum(k0, self.n_steps - 1)]
        period = GyroPeriod(
            loglik_gain=np.full(self.n, np.nan) if gain is None else gain,
            errors=self._err,
            cov=self._cov if self.reward.uses_cov else None,
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
            errors=self._err[rows, np.maximum(steps - 1, 0)] / DISPLAY_SCALE,
            t_s=self.t[self.target.start + last],
        )

    def onset(self, row: int) -> float | None:
        """The drawn onset of episode ``row`` (truth, for evaluation); None without one."""
        v = float(self.onset_s[row])
        return None if np.isnan(v) else v


__all__ = ["DEFAULT_SCENARIOS", "GyroEpisodes", "GyroStep"]
