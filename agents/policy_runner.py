"""A saved policy as a method of its problem, through its environment's ``policy_runner``:
``policy:PATH`` of the problems whose methods run over simulated episodes
(``qkf judge redundant_gyros --methods constant,policy:PATH``).

Declared in the entry-point group ``qkf.gyro_method_factories`` (``pyproject.toml``), so the
problem resolves it without importing this package. The policy (:class:`agents.policy.Policy`:
any agent, its frame stack and LSTM state carried) acts deterministically on the observation of
the environment id it was trained on, built with the same options (action type, decision
period, observation version, ``env_kwargs``); which environment class runs the episodes and how
they are scored is the environment registry's ``policy_runner`` (``envs``), not this module's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from agents.policy import Policy
from agents.policy_sources import saved_spaces, split_spec
from envs import ENVIRONMENTS
from qkf.core.config import ConfigError
from qkf.core.registry import load_object


@dataclass(frozen=True)
class EpisodePolicyMethod:
    """``policy:PATH`` as a method over simulated episodes: ``(cfg, episodes, tuning)`` → the
    runner's score per episode (the tuning episodes are not used: a policy is not tuned)."""

    path: str

    @property
    def default_label(self) -> str:
        """``policy:<stem>``, or ``policy:<folder>`` for a model saved as ``model.*``."""
        p = Path(split_spec(self.path)[0])
        return f"policy:{p.parent.name if p.stem == 'model' and p.parent.name else p.stem}"

    def __call__(self, cfg: Any, episodes: Sequence[Any], tuning: Sequence[Any]) -> np.ndarray:
        policy = Policy(self.path)
        spec = ENVIRONMENTS[policy.cfg.env]
        assert spec.policy_runner is not None  # checked by the factory
        options = {
            "action_type": policy.cfg.action_type,
            "period_s": policy.cfg.period_s,
            **spec.kwargs,
            **dict(policy.cfg.env_kwargs or {}),
        }
        n_actions = None
        if policy.path.suffix == ".zip" and policy.cfg.action_type == "discrete":
            n_actions = saved_spaces(policy.path)[2]
        try:
            scores = load_object(spec.policy_runner)(policy, options, cfg, episodes, n_actions)
        except ValueError as exc:
            raise ConfigError(f"{self.path}: {exc}") from None
        return np.asarray(scores, dtype=float)


def policy_method(path: str) -> EpisodePolicyMethod:
    """Method factory of ``policy:PATH``; loads the model once up front, so a missing, corrupt
    or foreign file is refused before any work (``ConfigError``), as is a policy whose
    environment has no ``policy_runner``."""
    policy = Policy(path)
    if ENVIRONMENTS[policy.cfg.env].policy_runner is None:
        raise ConfigError(
            f"{path}: trained on {policy.cfg.env}, whose policies do not run over this "
            "problem's episodes (no policy_runner in the environment registry)"
        )
    return EpisodePolicyMethod(path)


__all__ = ["EpisodePolicyMethod", "policy_method"]
