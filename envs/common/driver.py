"""What every front end of an environment runs on: a *driver* that steps N episodes at once
(:class:`envs.transfer_alignment.episodes.EpisodeDriver`,
:class:`envs.redundant_gyros.episodes.GyroEpisodes`).

The single environment is episode 0 of a driver of one (:mod:`envs.common.single`), the
batched Gymnasium vector environment and the Stable-Baselines3 adapter are its N rows
(:mod:`envs.common.vector_batched`, :mod:`envs.common.sb3_batched`), so all three step the
same episodes the same way.
"""

from __future__ import annotations

from typing import Any, Protocol, TypeVar

import numpy as np
from gymnasium import spaces

from envs.common.actions import ActionMap


class BatchedDriver(Protocol):
    """N episodes stepped at once. Episode ``i`` draws from its own generator ``rngs[i]``, so
    sub-environment ``i`` seeded with ``s + i`` is the single environment seeded with ``s + i``.

    ``step(actions)`` returns one row per episode of ``obs``, ``reward``, ``terminated``,
    ``truncated``, ``kappa``, ``errors`` and ``t_s`` (the end of the period, s).
    """

    rngs: list[np.random.Generator]

    @property
    def cfg(self) -> Any:
        """The problem's config the episodes are drawn from."""
        ...

    @property
    def actions(self) -> ActionMap:
        """The κ action map."""
        ...

    @property
    def episode_steps(self) -> int:
        """Steps of a full episode, from the config."""
        ...

    @property
    def observation_space(self) -> spaces.Space[Any]:
        """The space of one episode's observation."""
        ...

    @property
    def action_space(self) -> spaces.Space[Any]:
        """The space of one episode's action."""
        ...

    def reset_envs(self, rows: np.ndarray) -> np.ndarray:
        """Start episodes ``rows`` anew, each from its generator; their first observations."""
        ...

    def step(self, actions: Any) -> Any:
        """Run one decision period of every episode with one action each."""
        ...


class EpisodeHooks:
    """What a problem's Gymnasium front end (single or batched) adds to its driver: the
    curves each frame of ``render()`` records and its own ``info`` entries."""

    def curves(self, out: Any) -> np.ndarray:
        """What each episode's frame records after step ``out`` (the driver's output):
        (episodes, curves)."""
        raise NotImplementedError

    def step_info(self, out: Any) -> dict[str, Any]:
        """``info`` entries of a step beyond ``kappa``, ``diverged`` and ``errors``."""
        return {}

    def reset_info(self) -> dict[str, Any]:
        """``info`` entries of a reset beyond ``kappa`` and ``diverged``."""
        return {}


DriverT = TypeVar("DriverT", bound=BatchedDriver)
"""The driver of a front end (its own type, for what the problem adds to the protocol)."""
