"""Training configs (``configs/train_*.yaml``): the schema and its loader (no torch needed).

::

    agent: ppo                 # a name of agents.algorithms.ALGORITHMS
    scenario: thermal_snap     # preset name or config path
    overrides: []              # --set style overrides of the scenario
    action_type: discrete      # must suit the agent (sac: continuous)
    reward: likelihood         # a name of envs.rewards.REWARDS
    period_s: 10               # decision period of the environment, s
    n_envs: 16
    seed: 0
    total_steps: 100000        # SB3: environment steps; tabular: see episodes
    episodes: 200              # tabular
    eval: {episodes: 8, seed: 100000, every_steps: 20000}
    hyperparams: {}            # keyword arguments of the SB3 algorithm
    tabular: {alpha: 0.1, ...} # TabularQAgent fields
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator

from agents.algorithms import ALGORITHMS
from envs.rewards import REWARDS
from qkf.core import presets
from qkf.core.config import ConfigError, StrictModel, load_model


class EvalConfig(StrictModel):
    episodes: Annotated[int, Field(ge=1)] = 8
    seed: Annotated[int, Field(ge=0)] = 100_000  # held out: training seeds start at ``seed``
    every_steps: Annotated[int, Field(ge=1)] = 20_000


class TrainConfig(StrictModel):
    agent: str
    scenario: str = "paper"
    overrides: list[str] = Field(default_factory=list)
    action_type: Literal["discrete", "continuous"] = "discrete"
    reward: str = "likelihood"
    period_s: Annotated[float, Field(gt=0.0)] = 10.0
    n_envs: Annotated[int, Field(ge=1)] = 8
    seed: Annotated[int, Field(ge=0)] = 0
    total_steps: Annotated[int, Field(ge=1)] = 50_000
    episodes: Annotated[int, Field(ge=1)] = 100
    eval: EvalConfig = EvalConfig()
    hyperparams: dict[str, Any] = Field(default_factory=dict)
    tabular: dict[str, Any] = Field(default_factory=dict)
    torch_threads: Annotated[int, Field(ge=1)] = 1  # 2-core machines: the env wants the other

    @field_validator("agent")
    @classmethod
    def _known_agent(cls, v: str) -> str:
        if v not in ALGORITHMS:
            raise ValueError(f"unknown agent {v!r}; known: {', '.join(ALGORITHMS.names())}")
        return v

    @field_validator("reward")
    @classmethod
    def _known_reward(cls, v: str) -> str:
        if v not in REWARDS:
            raise ValueError(f"unknown reward {v!r}; known: {', '.join(REWARDS.names())}")
        return v


def load_train_config(path: str | Path, sets: list[str] | None = None) -> TrainConfig:
    """Read and validate a training config (path or preset name); ``ConfigError`` names the
    file and the field."""
    path = presets.resolve(path)
    cfg = load_model(TrainConfig, path, sets, "training config")
    allowed = ALGORITHMS[cfg.agent].action_types
    if cfg.action_type not in allowed:
        raise ConfigError(f"{path}: action_type: {cfg.agent} needs {' or '.join(allowed)} actions")
    return cfg
