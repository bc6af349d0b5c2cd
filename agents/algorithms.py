"""Agent algorithms by name: a registry (docs/architecture.md, "Add an agent").

Each entry says which action types the algorithm handles, how to get its class, the policy it
is built with and whether that policy is recurrent (``recurrent_ppo``: sb3-contrib's
``RecurrentPPO`` with an LSTM, whose ``predict`` carries a hidden state). Every class keeps
Stable-Baselines3's model contract (the constructor's ``env``, ``seed``, ``tensorboard_log``,
``device``; ``learn``, ``save``, ``load``, ``predict``), the tabular agent included, so one
runner trains them all (``agents/training/runner.py``). The classes are imported only when
asked for, so reading a training config or running a tabular policy does not load torch.
Installed packages can add algorithms through the entry-point group ``qkf.agents`` (an
:class:`Algorithm` object).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from qkf.core.registry import Registry


@dataclass(frozen=True)
class Algorithm:
    """An agent algorithm: ``load()`` returns its class, and what ``qkf train`` does
    differently for it: its constructor's arguments, the format of its model and what its
    training counts. Every such difference lives here, not in the training code.
    """

    action_types: tuple[str, ...]
    load: Callable[[], Any]
    description: str
    policy: str | None = "MlpPolicy"  # the SB3 policy class it is built with (None: no policy)
    recurrent: bool = False  # the policy carries a hidden state between steps (predict(state=))
    # a Stable-Baselines3 algorithm: rollouts round total_steps, imitation can pre-train it,
    # its hyperparams are checked against its __init__
    sb3: bool = True
    settings: str = "hyperparams"  # the training config field of its constructor's keywords
    model_suffix: str = ".zip"  # SB3's save format; the tabular agent's is .npz
    unit: str = "steps"  # what training (learn's total) counts: environment steps, or episodes
    budget: str = "total_steps"  # the training config field that says how long to train
    counter: str = "num_timesteps"  # the model's attribute, and training.json's field, of it

    @property
    def model_file(self) -> str:
        """The final model's file name in a run folder (``model.zip``)."""
        return "model" + self.model_suffix

    def checkpoint_name(self, progress: int) -> str:
        """A checkpoint's file name: SB3's ``CheckpointCallback`` naming (prefix ``model``,
        ``model_<steps>_steps.zip``), or its counterpart in this algorithm's unit."""
        return f"model_{progress}_{self.unit}{self.model_suffix}"

    def checkpoint_progress(self, name: str) -> int | None:
        """The progress in a checkpoint's file name; None if it is not this algorithm's."""
        pattern = rf"^model_(\d+)_{re.escape(self.unit)}{re.escape(self.model_suffix)}$"
        m = re.match(pattern, name)
        return None if m is None else int(m.group(1))


def _sb3(name: str) -> Callable[[], Any]:
    def load() -> Any:
        import stable_baselines3

        return getattr(stable_baselines3, name)

    return load


def _tabular() -> Any:
    from agents.tabular import TabularQAgent

    return TabularQAgent


ALGORITHMS: Registry[Algorithm] = Registry("agent", group="qkf.agents")
"""Agents for ``agent:`` of a training config."""
ALGORITHMS.register(
    "tabular",
    Algorithm(
        ("discrete",),
        _tabular,
        "tabular Q-learning (agents.tabular)",
        policy=None,
        sb3=False,
        settings="tabular",
        model_suffix=".npz",
        unit="episodes",
        budget="episodes",
        counter="episodes",
    ),
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
    """The model class of an agent (an SB3 algorithm, or the tabular agent)."""
    return ALGORITHMS[name].load()
