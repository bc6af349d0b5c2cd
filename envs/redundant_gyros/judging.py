"""A κ policy over the gyro problem's episodes (``policy:PATH`` of ``qkf judge redundant_gyros``;
docs/redundant_gyros.md, "Methods").

The judged episodes (:func:`qkf.redundant_gyros.hindsight.episode`, exactly those of
``env.reset(seed=...)``) are loaded into one batched environment
(:class:`~envs.redundant_gyros.episodes.GyroEpisodes`) with the policy's own options
(observation version, action type, decision period, ``env_kwargs``); the policy acts on each
decision period's observation, as in training, and every episode is scored by the hindsight's
``J`` (:mod:`qkf.redundant_gyros.methods`). The environment registry names this function as the
gyro ids' ``policy_runner``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from envs.common import ActingPolicy
from envs.redundant_gyros.episodes import GyroEpisodes
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.hindsight import Episode


def check_policy(
    options: Mapping[str, Any], cfg: GyrosConfig, n_actions: int | None = None
) -> None:
    """Whether a saved policy choosing among ``n_actions`` discrete actions can run on ``cfg``
    (before any work): ``TypeError`` for another problem's config, ``ValueError`` for another
    number of actions than the config's action set (``environment.actions``). ``options`` are
    not needed: every gyro id takes its action set from the config."""
    if not isinstance(cfg, GyrosConfig):
        raise TypeError("a gyro policy runs over gyro episodes of a gyro config only")
    count = cfg.environment.actions.count
    if n_actions is not None and n_actions != count:
        raise ValueError(
            f"the policy chooses among {n_actions} actions, but the config's action set "
            f"(environment.actions) has {count}"
        )


def run_policy(
    policy: ActingPolicy,
    options: Mapping[str, Any],
    cfg: GyrosConfig,
    episodes: Sequence[Episode],
    n_actions: int | None = None,
    describe: str = "policy",
) -> np.ndarray:
    """``J`` per episode (``inf`` where the filter fails) of ``policy`` acting in the gyro
    environment built with ``options`` (``GyroEpisodes``' keywords) over ``episodes`` of
    ``cfg``. ``TypeError`` for another problem's config or episodes; ``ValueError`` when the
    policy chooses among ``n_actions`` discrete actions and the config's action set has
    another number. ``describe`` is not used (the output is a number per episode)."""
    if not all(isinstance(e, Episode) for e in episodes):
        raise TypeError("a gyro policy runs over gyro episodes of a gyro config only")
    check_policy(options, cfg, n_actions)
    n = len(episodes)
    # the score is J, whatever the policy was trained on: the cheapest reward
    env = GyroEpisodes(n, cfg, **{**options, "reward": "oracle"})
    for i, ep in enumerate(episodes):
        env.load(i, ep.inputs)
    env.restart(np.arange(n))
    obs = np.zeros((n, env.observation.size), dtype=np.float32)
    obs[:, -1] = env.start_position  # what reset gives: nothing seen yet, the κ position
    policy.reset(n)
    settled = np.array([ep.settled_from for ep in episodes])
    total = np.zeros(n)
    for _ in range(env.episode_steps):
        k0 = env.k.copy()
        step = env.step(policy.act(obs))
        total += env.settled_square(k0, settled)
        obs = step.obs
    j = total / ((env.n_steps - settled) * 4.0)
    return np.where(env.failed, np.inf, j)


__all__ = ["check_policy", "run_policy"]
