"""The environment registry: every qkf environment id with what training and the zoo need to
know of it (docs/environment.md, "The environment registry").

``envs.ENVIRONMENTS[id]`` is an :class:`Environment`: the reward registry the id's ``reward=``
names, its observation version and size, the check of a ``scenario:`` (which problem's config
loader reads it), its batched Gymnasium vector environment and Stable-Baselines3 adapter, if
it has them. :func:`register_environment` puts an entry here and the id into Gymnasium's
registry, so the two cannot disagree. ``qkf train`` looks the id of a training config up here
and nowhere else; installed packages can add environments through the entry-point group
``qkf.environments`` (an :class:`Environment`, whose Gymnasium id their package registers).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from gymnasium.envs.registration import register
from gymnasium.envs.registration import registry as gym_registry

from qkf.core.registry import Registry


class ActingPolicy(Protocol):
    """What an environment's ``policy_runner`` needs of a saved policy: start ``n`` episodes,
    then its greedy actions for their newest observations (n, size)."""

    def reset(self, n: int) -> None: ...

    def act(self, obs: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class Environment:
    """One environment id and what its users need to know of it.

    ``entry_point``, ``vector_entry_point``, ``sb3_vec_env``: ``"module:Class"`` (Gymnasium's
    form; imported only when used, so the SB3 adapter costs no torch until it is asked for).
    ``check_scenario(scenario, overrides)``: the problems of a ``scenario:`` with its
    ``overrides``, one ``KEY: message`` line each (empty: it makes episodes).
    ``policy_runner``: how a saved policy of the id runs as a method of its problem, on that
    problem's simulated data (``policy:PATH``, :mod:`agents.policy`): called with the policy
    (:class:`ActingPolicy`), the environment options it was trained with (``observation``,
    ``action_type``, ``period_s``, the id's defaults and its ``env_kwargs``), the problem's
    config and data, the policy's number of discrete actions if known, and a description for
    the output's notes; ``ValueError`` when the policy does not fit the config.
    ``policy_check``: the same refusal before any work, from the options, the config and the
    number of actions alone (``fn(options, cfg, n_actions)``; the runner calls it too).
    ``datasets``: ``"module:object"`` whose ``plan(scenario, methods, trials, seed, controls,
    reward, period_s, out, overrides)`` checks a ``qkf dataset`` run before any work and whose
    ``make(plan, on_method)`` writes its Minari datasets (episodes of the id driven by methods).
    """

    id: str  # the Gymnasium id, "namespace/Name-vN"
    entry_point: str  # the single environment (gymnasium.Env)
    problem: str  # the qkf problem package of its scenarios ("transfer_alignment", …)
    rewards: Registry[Any]  # its rewards: names for reward= and a training config's reward:
    observation_size: int  # entries of its observation vector
    check_scenario: Callable[[str, Sequence[str]], list[str]]
    observation: str | None = None  # its observation version (observation= of the classes)
    vector_entry_point: str | None = None  # its batched gymnasium.vector.VectorEnv, if any
    sb3_vec_env: str | None = None  # its batched SB3 VecEnv adapter, if any
    description: str = ""
    # "module:function" running a saved policy as a method of its problem, if it has one:
    # fn(policy, options, cfg, data, n_actions, describe) → that problem's method output
    policy_runner: str | None = None
    policy_check: str | None = None  # "module:function": fn(options, cfg, n_actions), ValueError
    defaults: tuple[tuple[str, Any], ...] = ()  # keyword defaults of the id (v4: controls)
    options: tuple[str, ...] = ()  # keywords a training config's env_kwargs may set
    datasets: str | None = None  # "module:object": qkf dataset's plan and make, if it has them

    @property
    def kwargs(self) -> dict[str, Any]:
        """The constructor arguments the id fixes (the observation version, if any) and its
        keyword defaults."""
        fixed = {} if self.observation is None else {"observation": self.observation}
        return {**fixed, **dict(self.defaults)}


ENVIRONMENTS: Registry[Environment] = Registry("environment", group="qkf.environments")
"""Environments by Gymnasium id (``env:`` of a training config)."""


def register_environment(env: Environment) -> Environment:
    """Add ``env`` to :data:`ENVIRONMENTS` and its id to Gymnasium's registry. No
    ``max_episode_steps``: the environments truncate themselves at the end of the config's run,
    so ``gym.make`` and ``gym.make_vec`` agree for any duration."""
    ENVIRONMENTS.register(env.id, env)
    if env.id not in gym_registry:  # a re-import (importlib.reload) registers nothing twice
        register(
            id=env.id,
            entry_point=env.entry_point,
            vector_entry_point=env.vector_entry_point,
            max_episode_steps=None,
            kwargs=env.kwargs,
        )
    return env
