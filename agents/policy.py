"""A saved agent as a κ policy, and as a method of its problem: ``--methods policy:PATH``.

``policy:PATH`` is resolved through a problem's method-factory registry (transfer alignment's
``qkf.method_factories``, the gyros' ``qkf.gyro_method_factories``, declared in
``pyproject.toml``), so ``qkf`` itself never imports this package. The model's settings (which
agent, environment, action type, decision period and frame stack) come from the
``config.yaml`` that ``qkf train`` wrote beside it, from an RL Zoo3 run's own records, or, for a
bare Stable-Baselines3 zip, from ``policy:PATH@ENV_ID`` and the zip itself
(:mod:`agents.policy_sources`).

How the policy runs over its problem's simulated data is its environment's: the environment
registry's ``policy_runner`` (:data:`envs.ENVIRONMENTS`), called with the environment options it
was trained with; this module names no problem and no environment but through the registries.
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
from agents.policy_sources import (
    policy_config,
    saved_spaces,
    settings_files,
    split_spec,
    tabular_action_count,
)
from envs import ENVIRONMENTS
from qkf.core.config import ConfigError
from qkf.core.registry import load_object
from qkf.core.results_cache import code_fingerprint


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


@dataclass(frozen=True)
class PolicyMethod:
    """``policy:PATH`` as a method (picklable: it carries only the path)."""

    path: str

    @property
    def default_label(self) -> str:
        """``policy:<stem>``, or ``policy:<folder>`` for a model saved as ``model.*``."""
        p = Path(split_spec(self.path)[0])
        return f"policy:{p.parent.name if p.stem == 'model' and p.parent.name else p.stem}"

    def __call__(self, cfg: Any, data: Any, *rest: Any) -> Any:
        """The policy over ``data`` of ``cfg`` (its problem's method arguments; any further ones,
        such as the gyro methods' tuning episodes, are not used: a policy is not tuned)."""
        return run_policy(cfg, data, self.path)

    def check(self, cfg: Any) -> None:
        """``ConfigError`` when the policy cannot run on ``cfg`` (:func:`check_policy`): what
        a judging run asks of every method before any work."""
        check_policy(cfg, self.path)

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


def _environment_of(path: str) -> tuple[Any, Any, dict[str, Any], int | None]:
    """The settings of the saved policy at ``path``, its environment's registry entry, the
    environment options it was trained with, and its number of discrete actions (None for a
    continuous one). Reads the settings files and the zip's data record (a tabular agent's
    count from its ``.npz``) only."""
    model, settings = policy_config(path)
    spec = ENVIRONMENTS[settings.env]
    options = {
        "action_type": settings.action_type,
        "period_s": settings.period_s,
        **spec.kwargs,
        **dict(getattr(settings, "env_kwargs", {}) or {}),
    }
    n_actions = None
    if model.suffix == ".zip" and settings.action_type == "discrete":
        n_actions = saved_spaces(model)[2]
    elif model.suffix == ".npz":  # a tabular agent: its Q table's columns are its actions
        n_actions = tabular_action_count(model)
    return settings, spec, options, n_actions


def check_policy(cfg: Any, path: str) -> None:
    """``ConfigError`` when the saved policy at ``path`` cannot run on ``cfg`` (another action
    set, another problem's config), before any work: its environment's ``policy_check``."""
    _, spec, options, n_actions = _environment_of(path)
    if spec.policy_check is None:
        return
    try:
        load_object(spec.policy_check)(options, cfg, n_actions)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: {exc}") from None


def run_policy(cfg: Any, data: Any, path: str) -> Any:
    """The saved policy at ``path`` as a method of its problem on ``data`` of ``cfg``: its
    environment's ``policy_runner`` with the options it was trained with (``ConfigError`` when
    the policy does not fit the config, e.g. another action set)."""
    policy = Policy(path)
    settings, spec, options, n_actions = _environment_of(path)
    if spec.policy_runner is None:
        raise ConfigError(f"{path}: trained on {settings.env}, which has no policy_runner")
    runner = load_object(spec.policy_runner)
    describe = f"{settings.agent} policy from {path}"
    try:
        return runner(policy, options, cfg, data, n_actions, describe)
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None


@dataclass(frozen=True)
class PolicyFactory:
    """The ``policy:PATH`` method factory of one problem (its registry's entry point): loads
    the model once before any trial runs, so a missing, corrupt or foreign file is refused up
    front (``ConfigError``), as is a policy trained on another problem's environment."""

    problem: str

    def __call__(self, path: str) -> PolicyMethod:
        policy = Policy(path)
        spec = ENVIRONMENTS[policy.cfg.env]
        if spec.problem != self.problem or spec.policy_runner is None:
            raise ConfigError(
                f"{path}: trained on {policy.cfg.env}, not a {self.problem.replace('_', '-')} "
                "environment"
            )
        return PolicyMethod(path)


policy_method = PolicyFactory("transfer_alignment")
"""``policy:PATH`` of transfer alignment (entry point ``qkf.method_factories``)."""
episode_policy_method = PolicyFactory("redundant_gyros")
"""``policy:PATH`` of the redundant-gyro episodes (entry point ``qkf.gyro_method_factories``)."""
