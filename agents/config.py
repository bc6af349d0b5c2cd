"""Training configs (``configs/training/*.yaml``): the schema and its loader (no torch needed).

::

    agent: ppo                 # a name of agents.algorithms.ALGORITHMS
    env: qkf/TransferAlignment-v2  # an id of envs.ENVIRONMENTS (default: -v0)
    scenario: thermal_snap     # preset name or config path, of the environment's problem
    overrides: []              # --set style overrides of the scenario
    action_type: discrete      # must suit the agent (sac: continuous)
    reward: likelihood         # a name of the environment's rewards (ENVIRONMENTS[env].rewards)
    period_s: 10               # decision period of the environment, s
    n_envs: 16
    seed: 0
    total_steps: 100000        # SB3: environment steps; tabular: see episodes
    episodes: 200              # tabular
    eval: {episodes: 8, seed: 100000, every_steps: 20000}
    hyperparams: {}            # keyword arguments of the SB3 algorithm
    tabular: {alpha: 0.1, ...} # TabularQAgent fields
    reward_scale: 1.0          # the learner sees reward × this (evaluations do not)
    reward_clip: null          # … clipped to ±this after scaling (null: not clipped)
    frame_stack: 1             # SB3: the policy sees its last k observations (VecFrameStack)
    env_kwargs: {}             # keywords of the environment (ENVIRONMENTS[env].options)
    imitation:                 # SB3 actor-critic agents: DAgger from the env's expert first
      rounds: 4                # (env_kwargs must choose the expert, e.g. {expert: ...})
      steps_per_round: 2048    # environment steps per round (all n_envs together)
      beta0: 1.0               # round r follows the expert with probability beta0·beta_decay^r
      beta_decay: 0.5
      epochs: 10               # behavioural cloning on all rounds' data after each round
      batch_size: 256
      learning_rate: 0.001
      then_rl: true            # then total_steps of the agent's own learning (false: stop)

:func:`load_train_config` checks everything a training run will use before any work, and
reports every problem at once, one line each (``FILE: dotted.field: message``): the schema,
the action type against the agent, the reward against the environment's, the scenario and its
``overrides`` (loaded as the run will load them, by the environment's own check), the
``hyperparams`` against the SB3 algorithm's constructor (this imports SB3, so only for SB3
agents: a tabular policy never loads torch), the ``tabular`` settings (bins against the
environment's observation size), ``env_kwargs`` against the environment's ``options`` and
``imitation`` against the agent and the environment (an actor-critic SB3 agent without memory,
an environment that can have an expert). Everything about the environment comes from its entry
in :data:`envs.ENVIRONMENTS`.

``imitation:`` (:class:`ImitationConfig`, :mod:`agents.imitation`): before its own learning, the
agent imitates the environment's expert by DAgger, ``rounds`` rounds of ``steps_per_round``
environment steps (rounded up to whole steps of all ``n_envs`` environments) with behavioural
cloning on everything collected so far after each; ``then_rl: false`` keeps the cloned policy
as the result. The expert is chosen by the environment's keyword ``expert`` in ``env_kwargs``.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator

from agents.algorithms import ALGORITHMS, algorithm_class
from envs import ENV_ID, ENVIRONMENTS
from qkf.core import presets
from qkf.core.config import ConfigError, StrictModel

HEADER = "invalid training config"

RESERVED_HYPERPARAMS = {
    "policy": "set by qkf train (the agent's policy: MlpPolicy, MlpLstmPolicy for "
    "recurrent_ppo); network options go in policy_kwargs",
    "env": "set by qkf train (the environment of the config)",
    "seed": "set by qkf train from the config's seed",
    "device": "set by qkf train (cpu)",
    "tensorboard_log": "set by qkf train (OUT/tb)",
}
"""Constructor arguments of an SB3 algorithm that ``qkf train`` passes itself."""

RESERVED_TABULAR = {
    "n_actions": "set by qkf train from the environment's actions",
    "seed": "set by qkf train from the config's seed",
    "env": "set by qkf train (the environment of the config)",
    "device": "set by qkf train (cpu)",
    "tensorboard_log": "set by qkf train (OUT/tb)",
}


class EvalConfig(StrictModel):
    episodes: Annotated[int, Field(ge=1)] = 8
    seed: Annotated[int, Field(ge=0)] = 100_000  # held out: training seeds start at ``seed``
    every_steps: Annotated[int, Field(ge=1)] = 20_000


class ImitationConfig(StrictModel):
    """DAgger before reinforcement learning (:func:`agents.imitation.dagger`)."""

    rounds: Annotated[int, Field(ge=1)] = 4
    # environment steps per round, all n_envs together (like total_steps); collected as
    # ceil(steps_per_round / n_envs) steps of the vectorised environment
    steps_per_round: Annotated[int, Field(ge=1)] = 2048
    beta0: Annotated[float, Field(ge=0.0, le=1.0)] = 1.0  # round r: expert w.p. beta0·decay^r
    beta_decay: Annotated[float, Field(ge=0.0, le=1.0)] = 0.5
    epochs: Annotated[int, Field(ge=1)] = 10  # cloning epochs over the aggregate, every round
    batch_size: Annotated[int, Field(ge=1)] = 256
    learning_rate: Annotated[float, Field(gt=0.0)] = 1e-3
    then_rl: bool = True  # then total_steps of the agent's own learning; False: cloned only

    def vector_steps(self, n_envs: int) -> int:
        """Steps of the ``n_envs``-environment VecEnv per round (``steps_per_round`` rounded
        up to a multiple of ``n_envs``)."""
        return -(-self.steps_per_round // n_envs)


class TrainConfig(StrictModel):
    agent: str
    env: str = ENV_ID  # configs written before env: existed train on the v0 environment
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
    reward_scale: Annotated[float, Field(gt=0.0)] = 1.0  # every agent learns from reward × this
    # SB3: and then clipped to ±this (heavy-tailed rewards); evaluations see the reward as is
    reward_clip: Annotated[float, Field(gt=0.0)] | None = None
    frame_stack: Annotated[int, Field(ge=1)] = 1  # SB3: the policy sees the last k observations
    env_kwargs: dict[str, Any] = Field(default_factory=dict)  # ENVIRONMENTS[env].options
    imitation: ImitationConfig | None = None  # DAgger from the env's expert before RL

    @field_validator("agent")
    @classmethod
    def _known_agent(cls, v: str) -> str:
        return ALGORITHMS.known(v, "agent")

    @field_validator("env")
    @classmethod
    def _known_env(cls, v: str) -> str:
        return ENVIRONMENTS.known(v, "env")

    @field_validator("reward")
    @classmethod
    def _known_reward(cls, v: str) -> str:
        """A reward of some environment (the env's own are checked with the whole config)."""
        known = list(dict.fromkeys(n for e in ENVIRONMENTS for n in ENVIRONMENTS[e].rewards))
        if v not in known:
            raise ValueError(f"unknown reward {v!r}; known: {', '.join(known)}")
        return v


PRESETS = "training"
"""The training configs' preset folder (``configs/training/``)."""


def train_config_source(path: str | Path, sets: list[str] | None = None) -> str:
    """How messages name a training config: its resolved file, ``(with --set)`` if overridden."""
    return f"{presets.resolve(path, PRESETS)}" + (" (with --set)" if sets else "")


def load_train_config(
    path: str | Path, sets: list[str] | None = None, *, check_scenario: bool = True
) -> TrainConfig:
    """Read and validate a training config (path or preset name); ``ConfigError`` names the
    file and the field. ``check_scenario=False`` skips loading the scenario (a saved policy
    acts on any scenario; its training scenario may be a path relative to another folder)."""
    cfg = presets.load_preset(TrainConfig, path, PRESETS, sets, "training config")
    validate_train_config(cfg, train_config_source(path, sets), check_scenario=check_scenario)
    return cfg


def validate_train_config(cfg: TrainConfig, source: str, *, check_scenario: bool = True) -> None:
    """Check what the schema cannot: ``ConfigError`` with one line per problem."""
    problems: list[str] = []
    algo = ALGORITHMS[cfg.agent]
    if cfg.action_type not in algo.action_types:
        needs = " or ".join(algo.action_types)
        problems.append(f"action_type: {cfg.agent} needs {needs} actions")
    env = ENVIRONMENTS[cfg.env]
    if cfg.reward not in env.rewards:
        problems.append(
            f"reward: {cfg.env} has no reward {cfg.reward!r}; known: {', '.join(env.rewards)}"
        )
    for key in cfg.env_kwargs:
        if key not in env.options:
            accepts = (
                f"accepts {', '.join(env.options)}" if env.options else "accepts no env_kwargs"
            )
            problems.append(f"env_kwargs.{key}: not a keyword {cfg.env} {accepts}")
    if check_scenario:
        problems += env.check_scenario(cfg.scenario, cfg.overrides)
    if cfg.imitation is not None:
        problems += _imitation_problems(cfg)
    if not algo.sb3:  # the tabular agent
        if cfg.hyperparams:
            problems.append(
                "hyperparams: the tabular agent takes no SB3 hyperparameters (use tabular:)"
            )
        problems += _tabular_problems(cfg.tabular, env.observation_size)
        if cfg.frame_stack != 1:
            problems.append("frame_stack: the tabular agent sees one observation (must be 1)")
    else:
        if algo.recurrent and cfg.frame_stack != 1:
            problems.append(f"frame_stack: {cfg.agent} keeps its own memory (an LSTM); must be 1")
        if cfg.tabular:
            problems.append(f"tabular: only the tabular agent reads it, not {cfg.agent}")
        problems += _hyperparam_problems(algorithm_class(cfg.agent), cfg.hyperparams)
    if problems:
        raise ConfigError(f"{HEADER}\n  " + "\n  ".join(f"{source}: {p}" for p in problems))


def _imitation_problems(cfg: TrainConfig) -> list[str]:
    """Imitation needs an SB3 actor-critic without memory and an environment with an expert."""
    algo = ALGORITHMS[cfg.agent]
    problems = []
    if not algo.sb3:
        problems.append("imitation: the tabular agent cannot imitate (an SB3 agent: ppo, a2c)")
    elif algo.recurrent:
        problems.append(
            f"imitation: {cfg.agent} keeps an LSTM state; imitation clones memoryless policies"
        )
    else:
        policy = algorithm_class(cfg.agent).policy_aliases.get(algo.policy)
        if policy is not None and not hasattr(policy, "evaluate_actions"):
            problems.append(
                f"imitation: {cfg.agent}'s policy has no action likelihood to clone with "
                "(an actor-critic agent: ppo, a2c)"
            )
    env = ENVIRONMENTS[cfg.env]
    if "expert" not in env.options:
        problems.append(f"imitation: {cfg.env} has no expert to imitate (no expert= keyword)")
    elif cfg.env_kwargs.get("expert", env.kwargs.get("expert")) is None:
        problems.append("imitation: needs env_kwargs.expert, the expert to imitate")
    return problems


def _unknown(key: str, known: list[str], owner: str) -> str:
    close = difflib.get_close_matches(key, known, n=1)
    return f"not a parameter of {owner}" + (f" (did you mean {close[0]}?)" if close else "")


def _hyperparam_problems(cls: Any, hyperparams: dict[str, Any]) -> list[str]:
    """Names against the algorithm's ``__init__``; the values are checked by the algorithm when
    ``qkf train`` builds it (still before anything is written)."""
    params = inspect.signature(cls.__init__).parameters
    open_ended = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    known = [
        n
        for n, p in params.items()
        if n != "self" and not n.startswith("_") and n not in RESERVED_HYPERPARAMS
        and p.kind not in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
    ]  # fmt: skip
    problems = []
    for key, value in hyperparams.items():
        if key in RESERVED_HYPERPARAMS:
            problems.append(f"hyperparams.{key}: {RESERVED_HYPERPARAMS[key]}")
        elif key not in known and not open_ended:
            problems.append(f"hyperparams.{key}: {_unknown(key, known, cls.__name__)}")
        elif key == "n_steps" and (
            isinstance(value, bool) or not isinstance(value, int) or value < 1
        ):
            problems.append(f"hyperparams.n_steps: must be a positive integer, got {value!r}")
    return problems


def _tabular_problems(tabular: dict[str, Any], obs_size: int) -> list[str]:
    from agents.tabular import TabularQAgent

    known = [
        f.name
        for f in dataclasses.fields(TabularQAgent)
        if f.init and f.name not in RESERVED_TABULAR
    ]
    problems = []
    for key in tabular:
        if key in RESERVED_TABULAR:
            problems.append(f"tabular.{key}: {RESERVED_TABULAR[key]}")
        elif key not in known:
            problems.append(f"tabular.{key}: {_unknown(key, known, 'the tabular agent')}")
    if problems:
        return problems
    try:
        agent = TabularQAgent(n_actions=2, **tabular)
    except (TypeError, ValueError) as exc:
        msg = str(exc)
        field = msg.split(":", 1)[0]
        if field.split(".")[0] in known:
            return [f"tabular.{msg}"]
        return [f"tabular: {msg}"]
    outside = [d for d in agent.bins if d >= obs_size]
    if outside:
        return [f"tabular.bins: {outside[0]} is not an observation index (0 to {obs_size - 1})"]
    return []
