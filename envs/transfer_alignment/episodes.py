"""Batched episodes of the transfer-alignment task: what every front end shares (the single
environment, the batched Gymnasium vector environment, its Stable-Baselines3 adapter and the
``policy:`` benchmark method).

N episodes run in one :class:`~qkf.transfer_alignment.filter.TransferAlignmentKF` (plus its
nominal κ = 1 shadow for the likelihood gain); each episode keeps its own epoch counter, so
episodes that end early restart independently of the others. :class:`EpisodeDriver` adds the
action map (:class:`envs.common.ActionMap`) and one generator per episode. The observation and
rewards are documented in docs/environment.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from envs.common.actions import ActionMap
from envs.common.bounds import DIVERGENCE_REWARD, observation_box
from envs.transfer_alignment.controls import ControlMap
from envs.transfer_alignment.experts import make_expert
from envs.transfer_alignment.observations import OBSERVATIONS, PeriodView
from envs.transfer_alignment.rewards import REWARDS, PeriodOutcome
from qkf.transfer_alignment.config import Config, load_scenario
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.methods.base import decision_steps
from qkf.transfer_alignment.metrics import state_errors, window_masks
from qkf.transfer_alignment.moves import Moves, apply_moves
from qkf.transfer_alignment.params import FilterParams, n_epochs
from qkf.transfer_alignment.recorded.grid import RecordedSet, load_recorded
from qkf.transfer_alignment.scenario import ScenarioData, simulate
from qkf.transfer_alignment.states import DISPLAY_UNIT

DEFAULT_PERIOD_S = 10.0
"""Decision period of the environments, s (one step = this much filtering)."""


@dataclass
class StepOutput:
    obs: np.ndarray  # (N, size of the observation) float32
    reward: np.ndarray  # (N,)
    terminated: np.ndarray  # (N,) bool
    truncated: np.ndarray  # (N,) bool
    kappa: np.ndarray  # (N,)
    errors: np.ndarray  # (N, 15) display units, at the end of the period
    crlb: np.ndarray  # (N, 15) display units
    t_s: np.ndarray  # (N,)
    est: np.ndarray  # (N, period, 16) the filter's estimates over the period, SI
    valid: np.ndarray  # (N, period) bool: epochs inside the episode
    nis: np.ndarray  # (N, period) the filter's NIS per epoch (NaN where none)
    moves: Moves | None = None  # the moves of the period (v4's controls), if any


class BatchedEpisodes:
    """N synchronous episodes; ``reset(i, seed)`` starts episode i anew from ``seed``.

    Besides the agent's filter it runs, only where asked for: a κ = 1 shadow restarted from the
    agent's state every period (the likelihood gain of the ``likelihood`` reward and the v0
    observation) and a free-running reference filter at the nominal κ (the ``*_gain`` rewards).
    """

    def __init__(
        self,
        cfg: Config,
        n: int,
        reward: str,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        recorded: RecordedSet | None = None,
    ) -> None:
        self.cfg = cfg
        self.n = n
        self.reward_kind = reward
        self.reward = REWARDS[reward]
        # replay of recorded runs (docs/recorded_data.md): episodes are its files; without
        # truth there is no reward (0) and no CRLB or reference filter to compute for one
        self.recorded = recorded
        self.reward_available = recorded is None or recorded.has_truth
        self.observation_kind = OBSERVATIONS[observation]
        self.observation = self.observation_kind.factory(cfg, n, period_s)
        self.needs_likelihood = (
            self.reward.needs_likelihood or self.observation_kind.needs_likelihood
        )
        self.params = FilterParams.from_config(cfg)
        self.kappas = np.asarray(cfg.adaptive.actions.values())
        self.period = decision_steps(period_s, cfg.scenario.dt_s)
        self._start_pos = cfg.adaptive.actions.nominal_index() / (self.kappas.size - 1)
        self.n_epochs = n_epochs(cfg.scenario)
        self.episode_steps = math.ceil(self.n_epochs / self.period)
        # the config's simulated trajectory: for recorded data with truth an approximation
        self.bound = (
            crlb(cfg).bound
            if self.reward_available
            else np.full((n_epochs(cfg.scenario), 15), np.nan)
        )
        # the state_settled weights (a CRLB run), for the *_gain rewards' reference only
        self.needs_reference = self.reward.needs_reference and self.reward_available
        self.weights = state_weights(cfg) if self.needs_reference else None
        ne = self.n_epochs
        self.gyro = np.zeros((n, ne, 3))
        self.ads_q = np.zeros((n, ne, 4))
        self.ads_rate = np.zeros((n, ne, 3))
        self.q_true = np.zeros((n, ne, 4))
        self.bias = np.zeros((n, ne, 3))
        self.calib = np.zeros((n, ne, 9))
        self.has_meas = np.ones((n, ne), dtype=bool)
        self.t = np.arange(ne) * cfg.scenario.dt_s
        self.k = np.zeros(n, dtype=np.int64)
        self.file_index = np.zeros(n, dtype=np.int64)  # recorded data: each episode's file
        self.kappa_pos = np.zeros(n)
        self.settled = window_masks(self.t, cfg.run.settled_s)["settled"]
        self._settled_epochs = max(int(self.settled.sum()), 1)
        # What a period that lies whole inside every episode reads, built once (a single
        # environment's step is a few hundred microseconds, and each small numpy call in it
        # costs one or two: docs/performance.md). Read-only: every step hands out the same
        # arrays. The bound and the settled window are views repeated over the episodes.
        self._rows = _read_only(np.arange(n))
        self._whole_valid = _read_only(np.ones((n, self.period), dtype=bool))
        self._whole_last = _read_only(np.full(n, self.period - 1))
        self._whole_steps = _read_only(np.full(n, self.period))
        self._no_errors = _read_only(np.full((n, self.period, 15), np.nan))
        self._bound_rows = np.broadcast_to(self.bound, (n, *self.bound.shape))
        self._settled_rows = np.broadcast_to(self.settled, (n, self.settled.size))
        self.nominal_kappa = float(self.kappas[cfg.adaptive.actions.nominal_index()])
        self.kf = TransferAlignmentKF(self.params, n)
        self.nominal = TransferAlignmentKF(self.params, n) if self.needs_likelihood else None
        # the free-running nominal-κ filter of the *_gain rewards: run over the whole episode
        # when it starts (its errors per epoch, and its settled mean square for the relative
        # rewards), since it does not depend on the agent
        self.reference_errors = np.zeros((n, ne, 15)) if self.needs_reference else None
        self.reference_ms = np.ones(n)  # settled state_settled² of the reference, per episode

    def reset(self, i: int, seed: int) -> np.ndarray:
        """Draw episode ``i`` from ``seed`` (recorded data: the file ``seed`` picks); returns
        its first observation."""
        return self.reset_many(np.array([i]), [seed])[0]

    def reset_many(self, rows: np.ndarray, seeds: Sequence[int]) -> np.ndarray:
        """:meth:`reset` of episodes ``rows``, each from its seed; their first observations
        (len(rows), size). The same episodes as one :meth:`reset` each, but the reference
        filter runs once for all of them: in a vector environment every episode ends at the
        same step, and one batch of reference filters runs in parallel (docs/performance.md)."""
        rows = np.asarray(rows, dtype=np.int64)
        for i, seed in zip(rows, seeds, strict=True):
            self._draw(int(i), int(seed))
        self._run_reference(rows)
        return self._restart(rows)

    def _draw(self, i: int, seed: int) -> None:
        """Episode ``i``'s data from ``seed`` and a fresh filter on it."""
        if self.recorded is None:
            d, row = simulate(self.cfg, seed, [0]), 0
        else:
            d = self.recorded.data
            row = int(np.random.default_rng(seed).integers(d.n_trials))
        self.file_index[i] = row
        self.gyro[i], self.ads_q[i], self.ads_rate[i] = d.gyro[row], d.ads_q[row], d.ads_rate[row]
        self.q_true[i], self.bias[i], self.calib[i] = d.q_true[row], d.bias[row], d.calib[row]
        self.has_meas[i] = d.has_meas if d.has_meas.ndim == 1 else d.has_meas[row]
        one = TransferAlignmentKF(self.params, 1)
        one.initialize(d.ads_q[row : row + 1, 0])
        self.kf.load_trial(i, one)

    def load(self, data: ScenarioData) -> np.ndarray:
        """Run the N episodes on given simulated data (N trials) instead of drawing them;
        returns the first observations (N, size)."""
        if data.n_trials != self.n or data.n_epochs != self.n_epochs:
            raise ValueError(f"data of {data.n_trials} trials × {data.n_epochs} epochs")
        self.gyro[:], self.ads_q[:], self.ads_rate[:] = data.gyro, data.ads_q, data.ads_rate
        self.q_true[:] = data.q_true
        self.bias[:], self.calib[:] = data.bias, data.calib
        self.has_meas[:] = data.has_meas
        self.kf.initialize(data.ads_q[:, 0])
        self._run_reference(np.arange(self.n))
        return self._restart(np.arange(self.n))

    def _run_reference(self, rows: np.ndarray) -> None:
        """The nominal-κ filter over the whole episode of ``rows``: its errors (SI) and its
        settled mean square of ``state_settled`` (weights :attr:`weights`)."""
        if self.reference_errors is None or self.weights is None:
            return
        ref = TransferAlignmentKF(self.params, rows.size)
        ref.initialize(self.ads_q[rows, 0])
        rec = ref.step(
            self.gyro[rows], self.ads_q[rows], self.ads_rate[rows], self.has_meas[rows],
            self.nominal_kappa,
        )  # fmt: skip
        err = state_errors(rec.est, self.q_true[rows], self.bias[rows], self.calib[rows])
        self.reference_errors[rows] = err
        with np.errstate(invalid="ignore", over="ignore"):  # a diverged reference: NaN below
            self.reference_ms[rows] = np.mean((err[:, self.settled] / self.weights) ** 2, (1, 2))

    def _restart(self, rows: np.ndarray) -> np.ndarray:
        """Epoch counter and κ of episodes ``rows`` back to the start; their first observations
        (zeros but for the κ in use)."""
        self.k[rows] = 0
        self.kappa_pos[rows] = self._start_pos
        return self.observation.reset(rows, self._start_pos)

    def _period_index(self, k0: np.ndarray) -> slice | np.ndarray:
        """Where the period of every episode lies in the episode arrays: a slice when all
        episodes are at the same epoch and the period fits (always, for one episode), else the
        epochs (N, period) of each, the last one repeated past the end."""
        first = int(k0[0])
        if first + self.period <= self.n_epochs and bool((k0 == first).all()):
            return slice(first, first + self.period)
        return np.minimum(k0[:, None] + np.arange(self.period)[None, :], self.n_epochs - 1)

    @staticmethod
    def _window(arr: np.ndarray, where: slice | np.ndarray) -> np.ndarray:
        """The period's epochs of ``arr`` (N, epochs, …) at ``where`` (:meth:`_period_index`):
        a view for a slice, a gather otherwise."""
        if isinstance(where, slice):
            return arr[:, where]
        return np.take_along_axis(arr, where.reshape(where.shape + (1,) * (arr.ndim - 2)), axis=1)

    def step(
        self, kappa: np.ndarray, kappa_pos: np.ndarray, moves: Moves | None = None
    ) -> StepOutput:
        """Run one decision period in every episode with process-noise factors ``kappa`` (N,);
        with ``moves`` (v4's controls) those moves instead, ``kappa`` their κ."""
        k0 = self.k.copy()
        where = self._period_index(k0)
        # Episodes are synchronous in length; a period that would run past the end is cut by
        # masking its extra epochs out as measurement-free repeats of the last one.
        if isinstance(where, slice):  # the whole period inside every episode
            valid, last, steps = self._whole_valid, self._whole_last, self._whole_steps
        else:
            valid = (k0[:, None] + np.arange(self.period)[None, :]) < self.n_epochs
            last = np.maximum(valid.sum(axis=1) - 1, 0)
            steps = np.maximum(valid.sum(axis=1), 1)  # an episode already over has none
        gyro, ads_q, ads_rate = (
            self._window(a, where) for a in (self.gyro, self.ads_q, self.ads_rate)
        )
        meas = self._window(self.has_meas, where) & valid
        if moves is not None:  # the period's process noise, assumed ADS σ and resets
            kappa = apply_moves(self.kf, moves)
        if self.nominal is not None:
            self.nominal.copy_state_from(self.kf)
            self.nominal.q_scale[:] = 1.0  # the shadow stays the nominal filter
            self.nominal.sigma_a[:] = self.params.sigma_a
        rec = self.kf.step(gyro, ads_q, ads_rate, meas, kappa, record_cov=self.reward.needs_cov)
        self.k = np.minimum(k0 + self.period, self.n_epochs)
        self.kappa_pos = kappa_pos
        rows = self._rows
        at = np.minimum(k0 + last, self.n_epochs - 1)  # the period's last valid epoch
        if self.reward.uses_truth:  # the errors over the whole period
            truth = (
                self._window(self.q_true, where),
                self._window(self.bias, where),
                self._window(self.calib, where),
            )
            err = state_errors(rec.est, *truth)
            err_last = err[rows, last]
        else:  # only info's errors at the period's last epoch; the reward does not see them
            truth = (self.q_true, self.bias, self.calib)
            if isinstance(where, slice):  # that epoch is the same in every episode: views
                a, j = where.stop - 1, self.period - 1
                one = (rec.est[:, j : j + 1], *(x[:, a : a + 1] for x in truth))
            else:
                one = (rec.est[rows, last][:, None], *(x[rows, at][:, None] for x in truth))
            err_last = state_errors(*one)[:, 0]
            err = self._no_errors
        ref_err = None
        if self.reference_errors is not None:
            ref_err = self._window(self.reference_errors, where)
        diverged = self.kf.diverged.copy()
        dll = None
        if self.nominal is not None:
            rec_nom = self.nominal.step(gyro, ads_q, ads_rate, meas, 1.0)
            ll, ll_nom = rec.loglik, rec_nom.loglik
            if not isinstance(where, slice):  # epochs past the end count nothing
                ll, ll_nom = np.where(valid, ll, 0.0), np.where(valid, ll_nom, 0.0)
            ll, ll_nom = ll.sum(axis=1), ll_nom.sum(axis=1)
            with np.errstate(invalid="ignore"):  # −inf − (−inf) once diverged: replaced below
                dll = ll - ll_nom
        if isinstance(where, slice):  # the bound and window of the epochs, per episode
            bound, settled = self._bound_rows[:, where], self._settled_rows[:, where]
        else:
            bound, settled = self.bound[where], self.settled[where] & valid
        outcome = PeriodOutcome(
            record=rec,
            loglik_gain=dll,
            errors=err,
            bound=bound,
            valid=valid,
            steps=steps,
            dt=self.cfg.scenario.dt_s,
            reference_errors=ref_err,
            settled=settled,
            settled_epochs=self._settled_epochs,
            weights=self.weights,
            reference_ms=self.reference_ms,
        )
        if self.reward_available:
            reward = np.asarray(self.reward.fn(outcome), dtype=float)
            reward = np.where(diverged | ~np.isfinite(reward), DIVERGENCE_REWARD, reward)
        else:  # recorded data without truth: no reward (divergence still ends the episode)
            reward = np.zeros(self.n)
        view = PeriodView(
            record=rec,
            valid=valid,
            last=last,
            steps=steps,
            loglik_gain=dll,
            elapsed=self.k / self.n_epochs,
            kappa_pos=self.kappa_pos,
            p0_sigma=self.params.p0_sigma,
            n_meas=self.params.n_meas,
            dt=self.cfg.scenario.dt_s,
            moves=moves,
        )
        return StepOutput(
            obs=self.observation(view),
            reward=reward,
            terminated=diverged,
            truncated=~diverged & (self.k >= self.n_epochs),
            kappa=np.asarray(kappa, dtype=float),
            errors=err_last / DISPLAY_UNIT,
            crlb=outcome.bound[rows, last] / DISPLAY_UNIT,
            t_s=self.t[at],
            est=rec.est,
            valid=valid,
            nis=rec.nis,
            moves=moves,
        )


class EpisodeOptions(TypedDict, total=False):
    """The keywords every front end of the task passes on to :class:`EpisodeDriver` (its
    defaults where one is left out): ``TransferAlignmentEnv(scenario, **options)`` and the
    batched ``(num_envs, scenario, **options)``."""

    action_type: Literal["discrete", "continuous"]
    reward: str
    overrides: list[str] | None
    period_s: float
    observation: str
    controls: str | None
    base: str | None
    expert: str | None


class EpisodeDriver:
    """What the environment front ends share: the config, the action map, the batched episodes
    and one generator per episode (each episode's data is drawn from its own generator).

    ``scenario``: a preset name, a config path or a :class:`Config`; ``reward``: a name of
    :data:`~envs.transfer_alignment.rewards.REWARDS`; ``period_s``: the decision period, s;
    ``observation``: a name of :data:`~envs.transfer_alignment.observations.OBSERVATIONS` (the
    environment version).
    """

    def __init__(
        self,
        n: int,
        scenario: str | Path | Config = "paper",
        action_type: str = "discrete",
        reward: str = "likelihood",
        overrides: list[str] | None = None,
        period_s: float = DEFAULT_PERIOD_S,
        observation: str = "v0",
        data: str | Path | Sequence[str | Path] | None = None,
        controls: str | None = None,
        base: str | None = None,
        expert: str | None = None,
    ) -> None:
        if n < 1:
            raise ValueError("num_envs must be at least 1")
        if reward not in REWARDS:
            raise ValueError(f"unknown reward {reward!r}; known: {', '.join(REWARDS.names())}")
        if not (np.isfinite(period_s) and period_s > 0.0):
            raise ValueError(f"period_s must be positive, got {period_s!r}")
        if observation not in OBSERVATIONS:
            known = ", ".join(OBSERVATIONS.names())
            raise ValueError(f"unknown observation {observation!r}; known: {known}")
        self.observation_version = observation
        self.cfg = scenario if isinstance(scenario, Config) else load_scenario(scenario, overrides)
        recorded = None
        if data is not None:  # the data set the step, duration and episodes (their files)
            paths = [data] if isinstance(data, str | Path) else list(data)
            recorded = load_recorded(self.cfg, paths)
            self.cfg = recorded.cfg
        self.actions = ActionMap(np.asarray(self.cfg.adaptive.actions.values()), action_type)
        if base is not None and controls is None:
            raise ValueError("base= (a residual) needs controls=")
        # v4: the moves the agent makes (envs.transfer_alignment.controls); None: κ only
        self.controls = (
            None
            if controls is None
            else ControlMap(self.cfg, controls, action_type, base, n, period_s)
        )
        self.action_space = self.actions.space if self.controls is None else self.controls.space
        self.observation_space: spaces.Box = observation_box(OBSERVATIONS[observation].size)
        self.core = BatchedEpisodes(self.cfg, n, reward, period_s, observation, recorded)
        self.rngs = [seeding.np_random()[0] for _ in range(n)]
        # the residual's base decision for each episode's next period
        base_rule = None if self.controls is None else self.controls.base
        self.base_moves = None if base_rule is None else base_rule.start()
        self.expert = make_expert(expert, self.controls, self.cfg, n, period_s)

    @property
    def episode_steps(self) -> int:
        """Steps of a full episode: ``ceil(epochs / period)``, from the config."""
        return self.core.episode_steps

    def reset_env(self, i: int) -> np.ndarray:
        """Start episode ``i`` anew from its generator; its first observation."""
        return self.reset_envs(np.array([i]))[0]

    def reset_envs(self, rows: np.ndarray) -> np.ndarray:
        """Start episodes ``rows`` anew, each from its own generator (drawn in the order of
        ``rows``); their first observations (len(rows), size)."""
        rows = np.asarray(rows, dtype=np.int64)
        seeds = [int(self.rngs[i].integers(2**63 - 1)) for i in rows]
        self.restart_base(rows)
        if self.expert is not None:
            self.expert.reset(rows)
        return self.core.reset_many(rows, seeds)

    def restart_base(self, rows: np.ndarray) -> None:
        """The residual's base rule and the controls' own state (``r_step``) back to their
        start for episodes ``rows``."""
        if self.controls is not None:
            self.controls.restart(rows)
        if self.controls is None or self.controls.base is None or self.base_moves is None:
            return
        self.controls.base.reset(rows)
        self.base_moves.put(rows, self.controls.base.start())

    def expert_actions(self) -> np.ndarray:
        """The expert's actions (``expert=``) for every episode's next period: (N,) for a
        one-dimensional action space, else (N, D); ``ValueError`` without an expert."""
        if self.expert is None or self.controls is None:
            raise ValueError("no expert: make the environment with expert= (v4)")
        actions = self.expert.actions(self.base_moves)
        return actions[:, 0] if isinstance(self.controls.space, spaces.Discrete) else actions

    def step(self, actions: Any) -> StepOutput:
        """Map one action per episode to κ (v4: to moves) and run one decision period in all
        of them."""
        if self.controls is not None:
            return self.step_moves(self.controls.moves(actions, self.core.n, self.base_moves))
        mapped = [self.actions(a) for a in actions]
        return self.core.step(np.array([m[0] for m in mapped]), np.array([m[1] for m in mapped]))

    def step_moves(self, moves: Moves) -> StepOutput:
        """Run one decision period with ``moves`` (N episodes), then let the residual's base
        rule decide the next period from it."""
        assert self.controls is not None
        out = self.core.step(moves.kappa, self.controls.kappa_position(moves.kappa), moves)
        base = self.controls.base
        if base is not None:
            self.base_moves = base(out.nis, out.valid, out.t_s)
        if self.expert is not None:
            self.expert.update(out)
        return out


def _read_only(arr: np.ndarray) -> np.ndarray:
    """``arr``, marked read-only (it is shared by every step that hands it out)."""
    arr.flags.writeable = False
    return arr
