"""Where a saved policy's settings come from, for ``policy:PATH`` (docs/zoo.md, "Judging a policy
trained elsewhere").

A policy acts through an environment: its id gives the observation, and the agent, the action
type, the decision period and the frame stack say how. Three kinds of saved model are read:

``qkf train`` (or ``qkf zoo``)
    ``model.zip`` / ``model.npz`` with the ``config.yaml`` that the training wrote beside it.
RL Zoo3
    ``logs/ALGO/ENV_N/ENV.zip`` with RL Zoo3's own record of the run in ``ENV_N/ENV/``:
    ``args.yml`` (``algo``, ``env``, ``env_kwargs``) and ``config.yml`` (``frame_stack``,
    ``env_kwargs``). ``env_kwargs`` given on RL Zoo3's command line replace the config's.
A bare Stable-Baselines3 zip: ``policy:PATH@ENV_ID``
    the environment named after ``@``. The algorithm is read from the zip's policy class (an
    actor-critic policy is run by PPO, which predicts as A2C does), the frame stack from the
    observation size over the environment's, the action type from the action space, and the
    decision period is the environment's default.

A model whose observation or action space does not fit the environment is refused before any
work, with both shapes in the message (:func:`check_spaces`).
"""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from agents.config import TrainConfig, validate_train_config
from envs import ENVIRONMENTS
from qkf.core.config import ConfigError, validate

RL_ZOO3_ALGOS = {
    "ppo": "ppo",
    "a2c": "a2c",
    "dqn": "dqn",
    "sac": "sac",
    "ppo_lstm": "recurrent_ppo",
}
"""RL Zoo3's ``--algo`` names and the agents they are here."""

POLICY_ALGOS = {
    "stable_baselines3.common.policies": "ppo",  # ActorCriticPolicy: PPO and A2C
    "stable_baselines3.dqn.policies": "dqn",
    "stable_baselines3.sac.policies": "sac",
    "sb3_contrib.common.recurrent.policies": "recurrent_ppo",
}
"""A bare zip's policy module and the agent that runs it."""


def split_spec(spec: str) -> tuple[str, str | None]:
    """``PATH@ENV_ID`` into the path and the environment id (None without ``@ENV_ID``)."""
    path, sep, env = spec.rpartition("@")
    # a Gymnasium id (namespace/Name-vN); a path may hold an '@' of its own
    if sep and re.fullmatch(r"[A-Za-z0-9_.-]+/[A-Za-z0-9_.-]+-v[0-9]+", env.strip()):
        return path, env.strip()
    return spec, None


class _RlZoo3Loader(yaml.SafeLoader):
    """YAML as RL Zoo3 writes it: its ``OrderedDict`` records read as plain mappings; any
    other Python object is refused (nothing is imported or called)."""


def _ordered_dict(loader: yaml.SafeLoader, node: yaml.Node) -> dict[str, Any]:
    args = loader.construct_sequence(node, deep=True)  # type: ignore[arg-type]
    return dict(args[0]) if args else {}


_RlZoo3Loader.add_constructor(
    "tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict
)


def _read_rl_zoo3(path: Path) -> dict[str, Any]:
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=_RlZoo3Loader)
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: not a readable RL Zoo3 record: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: not a mapping (an RL Zoo3 args.yml or config.yml)")
    return data


def rl_zoo3_folder(model: Path) -> Path | None:
    """RL Zoo3's record of the run that saved ``model`` (``ENV_N/ENV/`` beside ``ENV.zip``)."""
    folder = model.parent / model.stem
    return folder if (folder / "args.yml").is_file() else None


def _zip_data(model: Path) -> dict[str, Any]:
    try:
        with zipfile.ZipFile(model) as z:
            data = json.loads(z.read("data"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise ConfigError(f"{model}: not a Stable-Baselines3 zip ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{model}: not a Stable-Baselines3 zip (no data record)")
    return data


def saved_spaces(model: Path) -> tuple[list[int], str, int | None]:
    """A zip's observation shape, action-space type (``discrete``/``continuous``) and number of
    discrete actions (None for a box)."""
    data = _zip_data(model)
    try:
        shape = [int(v) for v in data["observation_space"]["_shape"]]
        action = data["action_space"]
        kind = str(action[":type:"])
        discrete = "Discrete" in kind
        # MultiDiscrete (v4's controls): several dimensions, no single count
        n = int(action["n"]) if discrete and "MultiDiscrete" not in kind else None
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"{model}: its data record has no observation or action space") from None
    return shape, "discrete" if discrete else "continuous", n


def tabular_action_count(model: Path) -> int:
    """The number of discrete actions a tabular agent's ``model.npz`` chooses among (the
    columns of its Q table), read without building the agent."""
    try:
        with np.load(model) as saved:
            return int(saved["n_actions"])
    except (OSError, KeyError, TypeError, ValueError):
        raise ConfigError(f"{model}: not a tabular agent's file (no n_actions record)") from None


def _train_config(fields: dict[str, Any], source: str) -> TrainConfig:
    cfg = validate(TrainConfig, fields, source, "policy settings")
    validate_train_config(cfg, source, check_scenario=False)
    return cfg


def _env_fields(env_kwargs: Any, source: str) -> dict[str, Any]:
    """The training-config fields an environment's keyword arguments set."""
    if env_kwargs is None:
        return {}
    if not isinstance(env_kwargs, dict):
        raise ConfigError(f"{source}: env_kwargs: not a mapping")
    known = ("scenario", "overrides", "action_type", "reward", "period_s")
    fields = {k: env_kwargs[k] for k in known if k in env_kwargs}
    # the environment's own keywords (v4: controls, base, expert) become the config's
    # env_kwargs; which ones an environment accepts is checked with the whole config
    rest = {k: v for k, v in env_kwargs.items() if k not in (*known, "observation", "render_mode")}
    if rest:
        fields["env_kwargs"] = rest
    return fields


def from_rl_zoo3(model: Path, folder: Path) -> TrainConfig:
    """The settings of an RL Zoo3 run from its ``args.yml`` and ``config.yml``."""
    args = _read_rl_zoo3(folder / "args.yml")
    config = _read_rl_zoo3(folder / "config.yml") if (folder / "config.yml").is_file() else {}
    source = str(folder / "args.yml")
    algo = str(args.get("algo", ""))
    if algo not in RL_ZOO3_ALGOS:
        raise ConfigError(
            f"{source}: algo {algo!r} is not one qkf runs; known: {', '.join(RL_ZOO3_ALGOS)}"
        )
    fields: dict[str, Any] = {"agent": RL_ZOO3_ALGOS[algo], "env": str(args.get("env", ""))}
    fields |= _env_fields(config.get("env_kwargs"), source)
    fields |= _env_fields(args.get("env_kwargs"), source)  # the command line's replace them
    fields["frame_stack"] = int(config.get("frame_stack") or 1)
    return _train_config(fields, source)


def from_bare_zip(model: Path, env: str) -> TrainConfig:
    """The settings of a bare SB3 zip run on ``env`` (module docstring)."""
    if env not in ENVIRONMENTS:
        raise ConfigError(f"policy:{model}@{env}: unknown environment; known: "
                          f"{', '.join(ENVIRONMENTS.names())}")  # fmt: skip
    data = _zip_data(model)
    module = str(data.get("policy_class", {}).get("__module__", ""))
    if module not in POLICY_ALGOS:
        raise ConfigError(f"{model}: policy class from {module or 'nowhere'}: not one qkf runs")
    shape, action_type, _ = saved_spaces(model)
    size = ENVIRONMENTS[env].observation_size
    if len(shape) != 1 or size is None or shape[0] % size:
        raise ConfigError(
            f"{model}: observations of shape {shape}, but {env} gives {size} entries (or a "
            "multiple of them, stacked): a policy of another environment"
        )
    fields = {"agent": POLICY_ALGOS[module], "env": env, "action_type": action_type,
              "frame_stack": shape[0] // size}  # fmt: skip
    return _train_config(fields, f"policy:{model}@{env}")


def policy_config(spec: str) -> tuple[Path, TrainConfig]:
    """The model file of ``spec`` (``PATH`` or ``PATH@ENV_ID``) and its settings; refused
    (``FileNotFoundError``/``ConfigError``) when the file or its settings are missing."""
    path, env = split_spec(spec)
    model = Path(path)
    if not path.strip():
        raise ConfigError(
            "no model path given (policy:PATH, e.g. policy:agents/zoo/best/model.zip)"
        )
    if model.is_dir():
        raise ConfigError(f"{path}: is a directory, not a model file (model.zip or model.npz)")
    if not model.is_file():
        raise FileNotFoundError(f"{path}: no such model file")
    if env is not None:
        return model, from_bare_zip(model, env)
    if (model.parent / "config.yaml").is_file():
        from agents.config import load_train_config

        # any scenario will do: the training one may be a path relative to elsewhere
        return model, load_train_config(model.parent / "config.yaml", check_scenario=False)
    folder = rl_zoo3_folder(model)
    if folder is not None:
        return model, from_rl_zoo3(model, folder)
    raise FileNotFoundError(
        f"{path}: no config.yaml beside the model (qkf train writes it), and no RL Zoo3 record "
        f"({model.stem}/args.yml); for a bare Stable-Baselines3 zip name its environment: "
        f"policy:{path}@ENV_ID (ENV_ID one of {', '.join(ENVIRONMENTS.names())})"
    )


def settings_files(spec: str) -> list[Path]:
    """The files besides the model that its settings are read from (for cache keys)."""
    path, env = split_spec(spec)
    model = Path(path)
    if env is not None:
        return []
    if (model.parent / "config.yaml").is_file():
        return [model.parent / "config.yaml"]
    folder = rl_zoo3_folder(model)
    return [] if folder is None else [p for p in (folder / "args.yml", folder / "config.yml")
                                      if p.is_file()]  # fmt: skip
