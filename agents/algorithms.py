"""Agent algorithms by name: a registry (docs/architecture.md, "Add an agent").

Each entry says which action types the algorithm handles, how to get its class, the policy it
is built with and whether that policy is recurrent (``recurrent_ppo``: sb3-contrib's
``RecurrentPPO`` with an LSTM, whose ``predict`` carries a hidden state). The SB3 classes are
imported only when asked for, so reading a training config or running a tabular
policy does not load torch. Installed packages can add algorithms through the entry-point group
``qkf.agents`` (an :class:`Algorithm` object).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from qkf.core.registry import Registry


@dataclass(frozen=True)
class Algorithm:
    """An agent algorithm: ``load()`` returns its class (None for the tabular agent)."""

    action_types: tuple[str, ...]
    load: Callable[[], Any] | None
    description: str
    policy: str = "MlpPolicy"  # the SB3 policy class name qkf train builds it with
    recurrent: bool = False  # the policy carries a hidden state between steps (predict(state=))


def _sb3(name: str) -> Callable[[], Any]:
    def load() -> Any:
        import stable_baselines3

        return getattr(stable_baselines3, name)

    return load


ALGORITHMS: Registry[Algorithm] = Registry("agent", group="qkf.agents")
"""Agents for ``agent:`` of a training config."""
ALGORITHMS.register(
    "tabular", Algorithm(("discrete",), None, "tabular Q-learning (agents.tabular)")
)
ALGORITHMS.register("dqn", Algorithm(("discrete",), _sb3("DQN"), "Stable-Baselines3 DQN"))
ALGORITHMS.register("ppo", Algorithm(("discrete", "continuous"), _sb3("PPO"), "SB3 PPO"))
ALGORITHMS.register("a2c", Algorithm(("discrete", "continuous"), _sb3("A2C"), "SB3 A2C"))
ALGORITHMS.register("sac", Algorithm(("continuous",), _sb3("SAC"), "Stable-Baselines3 SAC"))


def _sb3_contrib(name: str) -> Callable[[], Any]:
    def load() -> Any:
        import sb3_contrib

        return getattr(sb3_contrib, name)

    return load


ALGORITHMS.register(
    "recurrent_ppo",
    Algorithm(
        ("discrete", "continuous"),
        _sb3_contrib("RecurrentPPO"),
        "sb3-contrib RecurrentPPO (LSTM policy: memory of the episode so far)",
        policy="MlpLstmPolicy",
        recurrent=True,
    ),
)


def algorithm_class(name: str) -> Any:
    """The SB3 class of an agent; ``ValueError`` for one without (tabular)."""
    algo = ALGORITHMS[name]
    if algo.load is None:
        raise ValueError(f"agent {name!r} is not a Stable-Baselines3 algorithm")
    return algo.load()
