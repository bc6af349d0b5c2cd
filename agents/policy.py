"""A saved agent as a κ policy, and as a benchmark method: ``--methods policy:PATH``.

``policy:PATH`` is resolved through the method-factory registry of
:mod:`qkf.transfer_alignment.methods` (entry-point group ``qkf.method_factories``, declared in
``pyproject.toml``), so ``qkf`` itself never imports this package. The model needs the
``config.yaml`` its training wrote beside it (``qkf train`` does): it says which agent, action
type and decision period the policy was trained with.

The policy sees its environment's observation (the batched episodes of
:mod:`envs.transfer_alignment.episodes`, with the observation version of the id it was trained
on, from :data:`envs.ENVIRONMENTS`) every decision period and its action sets κ for the next
period; everything else is the filter of every other method, run on the same simulated trials.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.algorithms import algorithm_class
from agents.config import load_train_config
from envs import ENVIRONMENTS
from envs.common import ActionMap
from envs.transfer_alignment import BatchedEpisodes
from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput, per_epoch
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.scenario import ScenarioData


class Policy:
    """A saved agent (``model.npz``: tabular, ``model.zip``: SB3): ``act(obs (N, size))``."""

    def __init__(self, path: str | Path) -> None:
        path = _model_file(path)
        # any scenario will do: the training one may be a path relative to elsewhere
        self.cfg = load_train_config(path.parent / "config.yaml", check_scenario=False)
        self._model: Any = None  # SB3's predict() interface, which the tabular agent shares
        try:
            if path.suffix == ".npz":
                from agents.tabular import TabularQAgent

                self._model = TabularQAgent.load(path)
            else:
                self._model = algorithm_class(self.cfg.agent).load(path, device="cpu")
        except Exception as exc:  # a corrupt or foreign file: SB3/numpy raise many kinds
            what = " ".join(f"{type(exc).__name__}: {exc}".split())[:200]
            raise ConfigError(
                f"{path}: not a readable {self.cfg.agent} model (saved by qkf train?): {what}"
            ) from None

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The greedy actions for observations (N, size)."""
        action, _ = self._model.predict(obs, deterministic=True)
        return np.asarray(action)


def run_policy(cfg: Config, data: ScenarioData, path: str) -> MethodOutput:
    """Filter the trials with κ chosen by the saved policy at ``path``."""
    policy = Policy(path)
    actions = ActionMap(np.asarray(cfg.adaptive.actions.values()), policy.cfg.action_type)
    env = ENVIRONMENTS[policy.cfg.env]
    if env.problem != "transfer_alignment" or env.observation is None:
        raise ConfigError(
            f"{path}: trained on {policy.cfg.env}, not a transfer-alignment environment"
        )
    observation = env.observation
    core = BatchedEpisodes(
        cfg, data.n_trials, "likelihood", policy.cfg.period_s, observation=observation
    )
    obs = core.load(data)
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
    )


@dataclass(frozen=True)
class PolicyMethod:
    """``policy:PATH`` as a method (picklable: it carries only the path)."""

    path: str

    @property
    def default_label(self) -> str:
        """``policy:<stem>``, or ``policy:<folder>`` for a model saved as ``model.*``."""
        p = Path(self.path)
        return f"policy:{p.parent.name if p.stem == 'model' and p.parent.name else p.stem}"

    def __call__(self, cfg: Config, data: ScenarioData) -> MethodOutput:
        return run_policy(cfg, data, self.path)


def _model_file(path: str | Path) -> Path:
    """A saved model's path, checked: an existing file with the training's ``config.yaml``
    beside it (``FileNotFoundError`` / ``ConfigError`` otherwise)."""
    model = Path(path)
    if not str(path).strip():
        raise ConfigError(
            "no model path given (policy:PATH, e.g. policy:agents/zoo/best/model.zip)"
        )
    if model.is_dir():
        raise ConfigError(f"{path}: is a directory, not a model file (model.zip or model.npz)")
    if not model.is_file():
        raise FileNotFoundError(f"{path}: no such model file")
    if not (model.parent / "config.yaml").is_file():
        raise FileNotFoundError(
            f"{path}: no config.yaml beside the model (qkf train writes it; it names the agent, "
            "action type and decision period)"
        )
    return model


def policy_method(path: str) -> PolicyMethod:
    """Method factory of ``policy:PATH``; loads the model once before any trial runs, so a
    missing, corrupt or foreign file is refused up front (``ValueError``/``OSError``)."""
    Policy(path)
    return PolicyMethod(path)
