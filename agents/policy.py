"""A saved agent as a κ policy, and as a benchmark method: ``--methods policy:PATH``.

``policy:PATH`` is resolved through the method-factory registry of
:mod:`qkf.transfer_alignment.methods` (entry-point group ``qkf.method_factories``, declared in
``pyproject.toml``), so ``qkf`` itself never imports this package. The model's settings (which
agent, environment, action type, decision period and frame stack) come from the
``config.yaml`` that ``qkf train`` wrote beside it, from an RL Zoo3 run's own records, or, for a
bare Stable-Baselines3 zip, from ``policy:PATH@ENV_ID`` and the zip itself
(:mod:`agents.policy_sources`).

The policy sees its environment's observation (the batched episodes of
:mod:`envs.transfer_alignment.episodes`, with the observation version of the id it was trained
on, from :data:`envs.ENVIRONMENTS`) every decision period and its action sets κ for the next
period; everything else is the filter of every other method, run on the same simulated trials.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import envs
from agents.algorithms import ALGORITHMS, algorithm_class
from agents.config import TrainConfig
from agents.policy_sources import policy_config, saved_spaces, settings_files, split_spec
from envs import ENVIRONMENTS
from envs.common import ActionMap
from envs.transfer_alignment import BatchedEpisodes, EpisodeDriver
from qkf.core.config import ConfigError
from qkf.core.results_cache import code_fingerprint
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput, per_epoch
from qkf.transfer_alignment.methods.moves_schedule import MoveSchedule, run_moves
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.scenario import ScenarioData


class Policy:
    """A saved agent (``model.npz``: tabular, ``model.zip``: SB3): ``act(obs (N, size))``.

    It acts on N episodes that run in step, as it was trained: with ``frame_stack: k`` it sees
    its last k observations (oldest first, zeros before the first, as SB3's
    ``VecFrameStack``); a recurrent agent (``recurrent_ppo``) carries its LSTM state from one
    call to the next. :meth:`reset` starts new episodes (the first :meth:`act` does it too).
    """

    def __init__(self, path: str | Path) -> None:
        # a qkf run, an RL Zoo3 run, or PATH@ENV_ID (agents/policy_sources.py)
        path, self.cfg = policy_config(str(path))
        self.path = path
        self.recurrent = ALGORITHMS[self.cfg.agent].recurrent
        self.obs_size = ENVIRONMENTS[self.cfg.env].observation_size
        self.frame_stack = self.cfg.frame_stack
        if path.suffix == ".zip":
            _check_saved_model(path, self.cfg, self.obs_size * self.frame_stack)
        self._model: Any = None  # SB3's predict() interface, which every agent class keeps
        self._stacked: np.ndarray | None = None  # (N, size · k) the stacked observations
        self._state: Any = None  # the LSTM state of a recurrent policy
        self._starts = np.ones(0, dtype=bool)
        try:
            self._model = algorithm_class(self.cfg.agent).load(path, device="cpu")
        except Exception as exc:  # a corrupt or foreign file: SB3/numpy raise many kinds
            what = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
            raise ConfigError(
                f"{path}: not a readable {self.cfg.agent} model (saved by qkf train?): {what}"
            ) from None

    def reset(self, n: int) -> None:
        """Start n new episodes: empty frame stack, fresh LSTM state."""
        self._stacked = np.zeros((n, self.obs_size * self.frame_stack), dtype=np.float32)
        self._state = None
        self._starts = np.ones(n, dtype=bool)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The greedy actions for the N episodes' newest observations (N, size)."""
        obs = np.asarray(obs, dtype=np.float32)
        if self._stacked is None or self._stacked.shape[0] != obs.shape[0]:
            self.reset(obs.shape[0])
        assert self._stacked is not None
        if self.frame_stack > 1:  # SB3's VecFrameStack: shift left, newest last
            self._stacked = np.concatenate([self._stacked[:, self.obs_size :], obs], axis=1)
            obs = self._stacked
        if self.recurrent:
            action, self._state = self._model.predict(
                obs, state=self._state, episode_start=self._starts, deterministic=True
            )
            self._starts = np.zeros(obs.shape[0], dtype=bool)
        else:
            action, _ = self._model.predict(obs, deterministic=True)
        return np.asarray(action)


def run_policy(cfg: Config, data: ScenarioData, path: str) -> MethodOutput:
    """Filter the trials with κ chosen by the saved policy at ``path``."""
    policy = Policy(path)
    values = np.asarray(cfg.adaptive.actions.values())
    if (
        policy.path.suffix == ".zip"
        and policy.cfg.action_type == "discrete"
        and "controls" not in ENVIRONMENTS[policy.cfg.env].options
    ):
        _, _, n = saved_spaces(policy.path)
        if n is not None and n != values.size:
            raise ConfigError(
                f"{path}: chooses among {n} actions, but the config's action set "
                f"(adaptive.actions) has {values.size}: a policy trained on another action set"
            )
    actions = ActionMap(values, policy.cfg.action_type)
    env = ENVIRONMENTS[policy.cfg.env]
    if env.problem != "transfer_alignment" or env.observation is None:
        raise ConfigError(
            f"{path}: trained on {policy.cfg.env}, not a transfer-alignment environment"
        )
    observation = env.observation
    env_kwargs = {**env.kwargs, **dict(getattr(policy.cfg, "env_kwargs", {}) or {})}
    if env_kwargs.get("controls") is not None:  # v4: the policy makes the filter's moves
        return _run_moves_policy(cfg, data, policy, path, observation, env_kwargs)
    core = BatchedEpisodes(
        cfg, data.n_trials, "likelihood", policy.cfg.period_s, observation=observation
    )
    obs = core.load(data)
    policy.reset(data.n_trials)
    est = np.full((data.n_trials, data.n_epochs, 16), np.nan)
    kappa_log = []
    for k0 in range(0, data.n_epochs, core.period):
        mapped = [actions(a) for a in policy.act(obs)]
        kappa = np.array([m[0] for m in mapped])
        kappa_log.append(kappa)
        out = core.step(kappa, np.array([m[1] for m in mapped]))
        k1 = min(data.n_epochs, k0 + core.period)
        est[:, k0:k1] = out.est[:, : k1 - k0]
        obs = out.obs
    kappa = per_epoch(np.stack(kappa_log, axis=1), core.period, data.n_epochs)
    # the covariance the policy's filter believes, for NEES: the filter is deterministic given
    # its κ per epoch, so replaying that schedule reproduces it (same estimates, tested), and
    # the episode machinery need not record covariances at the sampled epochs itself
    replay = run_schedule(cfg, data, kappa)
    return MethodOutput(
        est=est,
        diverged=core.kf.diverged.copy(),
        kappa=kappa,
        notes={"policy": f"{policy.cfg.agent} policy from {path}"},
        cov=replay.cov,
        var=replay.var,
        innov=replay.innov,
        nis=replay.nis,
    )


def _run_moves_policy(
    cfg: Config,
    data: ScenarioData,
    policy: Policy,
    path: str,
    observation: str,
    env_kwargs: dict[str, Any],
) -> MethodOutput:
    """A v4 policy: its actions are moves of the environment's ``controls`` (a residual's on
    top of its ``base`` rule), made in the same episodes as in training; the output is
    :func:`~qkf.transfer_alignment.methods.moves_schedule.run_moves` of the moves it made
    (the same filter run, so the same estimates, with the covariance recorded)."""
    driver = EpisodeDriver(
        data.n_trials, cfg, policy.cfg.action_type, "oracle", None, policy.cfg.period_s,
        observation, controls=env_kwargs["controls"], base=env_kwargs.get("base"),
    )  # fmt: skip
    assert driver.controls is not None
    n = data.n_trials
    obs = driver.core.load(data)
    driver.restart_base(np.arange(n))
    policy.reset(n)
    made = []
    for _ in range(0, data.n_epochs, driver.core.period):
        moves = driver.controls.moves(policy.act(obs), n, driver.base_moves)
        made.append(moves)
        obs = driver.step_moves(moves).obs
    schedule = MoveSchedule.from_moves(driver.core.period, made)
    out = run_moves(cfg, data, schedule)
    out.diverged = out.diverged | driver.core.kf.diverged
    base = env_kwargs.get("base")
    out.notes["policy"] = (
        f"{policy.cfg.agent} policy from {path}: controls {env_kwargs['controls']}"
        + (f" on base {base}" if base else "")
    )
    return out


@dataclass(frozen=True)
class PolicyMethod:
    """``policy:PATH`` as a method (picklable: it carries only the path)."""

    path: str

    @property
    def default_label(self) -> str:
        """``policy:<stem>``, or ``policy:<folder>`` for a model saved as ``model.*``."""
        p = Path(split_spec(self.path)[0])
        return f"policy:{p.parent.name if p.stem == 'model' and p.parent.name else p.stem}"

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return run_policy(cfg, data, self.path)

    def cache_token(self) -> dict[str, Any]:
        """The policy in a results-cache key (docs/caching.md): the SHA-256 of the model file
        and of the files its settings come from (``config.yaml``, or RL Zoo3's records), the
        spec (its notes name it), and the code of the environments and agents that turn
        observations into κ."""
        model, _ = policy_config(self.path)
        return {
            "type": "agents.policy:PolicyMethod",
            "path": self.path,
            "model_sha256": _sha256(model),
            "settings_sha256": [_sha256(p) for p in settings_files(self.path)],
            "code": code_fingerprint([Path(envs.__file__).parent, Path(__file__).parent]),
        }


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check_saved_model(path: Path, cfg: TrainConfig, obs_size: int) -> None:
    """``ConfigError`` when the SB3 zip is not what ``config.yaml`` says: a recurrent policy
    saved beside a config of a feed-forward agent (or the reverse), or an observation of
    another size than the config's environment version gives (a policy trained on another
    version). Read from the zip's ``data`` record, before torch loads anything."""
    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
        module = str(data["policy_class"]["__module__"])
        shape = data["observation_space"]["_shape"]
    except (OSError, KeyError, TypeError, ValueError, zipfile.BadZipFile):
        return  # not SB3's layout: the load below reports it
    saved_recurrent = "recurrent" in module
    if saved_recurrent != ALGORITHMS[cfg.agent].recurrent:
        held = "a recurrent (LSTM) policy" if saved_recurrent else "a feed-forward policy"
        raise ConfigError(
            f"{path}: holds {held}, but its settings say agent {cfg.agent} "
            f"({'recurrent' if ALGORITHMS[cfg.agent].recurrent else 'feed-forward'}); "
            "the model and its config do not belong together"
        )
    if list(shape) != [obs_size]:
        raise ConfigError(
            f"{path}: expects observations of {list(shape)} entries, but its settings say env "
            f"{cfg.env} with frame_stack {cfg.frame_stack} ({obs_size} entries): a policy "
            "trained on another environment version"
        )


def policy_method(path: str) -> PolicyMethod:
    """Method factory of ``policy:PATH``; loads the model once before any trial runs, so a
    missing, corrupt or foreign file is refused up front (``ValueError``/``OSError``)."""
    Policy(path)
    return PolicyMethod(path)
