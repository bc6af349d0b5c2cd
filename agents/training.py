"""Training and evaluation of agents that choose κ: configs, SB3 models, the tabular agent.

A training config (``configs/train_*.yaml``)::

    agent: ppo                 # tabular | dqn | ppo | a2c | sac
    scenario: thermal_snap     # preset name or config path
    action_type: discrete      # sac needs continuous
    reward: likelihood
    n_envs: 16
    seed: 0
    total_steps: 100000        # SB3: environment steps; tabular: see episodes
    episodes: 200              # tabular
    eval: {episodes: 8, seed: 100000, every_steps: 20000}
    hyperparams: {}            # keyword arguments of the SB3 algorithm
    tabular: {alpha: 0.1, ...} # TabularQAgent fields

``train`` writes the model (``model.zip`` or ``model.npz``) and the config it used into the
output folder, TensorBoard logs under ``tb/``, checkpoints under ``checkpoints/`` (SB3), and
resumes from the newest checkpoint when one is there.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import torch
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from agents.common.vec_env import TransferAlignmentVecEnv
from agents.tabular import TabularQAgent, train_tabular
from qkf.transfer_alignment.config import ConfigError, apply_override
from qkf.core.io import atomic_write_text

ALGOS = ("dqn", "ppo", "a2c", "sac")


class EvalConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    episodes: Annotated[int, Field(ge=1)] = 8
    seed: Annotated[int, Field(ge=0)] = 100_000  # held out: training seeds start at ``seed``
    every_steps: Annotated[int, Field(ge=1)] = 20_000


class TrainConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    agent: Literal["tabular", "dqn", "ppo", "a2c", "sac"]
    scenario: str = "paper"
    overrides: list[str] = Field(default_factory=list)
    action_type: Literal["discrete", "continuous"] = "discrete"
    reward: Literal["likelihood", "oracle", "nees"] = "likelihood"
    n_envs: Annotated[int, Field(ge=1)] = 8
    seed: Annotated[int, Field(ge=0)] = 0
    total_steps: Annotated[int, Field(ge=1)] = 50_000
    episodes: Annotated[int, Field(ge=1)] = 100
    eval: EvalConfig = EvalConfig()
    hyperparams: dict[str, Any] = Field(default_factory=dict)
    tabular: dict[str, Any] = Field(default_factory=dict)
    torch_threads: Annotated[int, Field(ge=1)] = 1  # 2-core machines: the env wants the other


def load_train_config(path: str | Path, sets: list[str] | None = None) -> TrainConfig:
    """Read and validate a training config; ``ConfigError`` names the file and the field."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such training config")
    try:
        data = yaml.safe_load(path.read_text()) or {}
        for item in sets or []:
            apply_override(data, item)
        cfg = TrainConfig.model_validate(data)
    except (ValidationError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: invalid training config: {exc}") from None
    if cfg.agent == "sac" and cfg.action_type != "continuous":
        raise ConfigError(f"{path}: action_type: sac needs continuous actions")
    if cfg.agent in ("dqn", "tabular") and cfg.action_type != "discrete":
        raise ConfigError(f"{path}: action_type: {cfg.agent} needs discrete actions")
    return cfg


def make_vec_env(cfg: TrainConfig, n_envs: int, seed: int) -> TransferAlignmentVecEnv:
    env = TransferAlignmentVecEnv(
        n_envs, cfg.scenario, cfg.action_type, cfg.reward, overrides=list(cfg.overrides)
    )
    env.seed(seed)
    return env


def _monitored(env: TransferAlignmentVecEnv) -> Any:
    from stable_baselines3.common.vec_env import VecMonitor

    return VecMonitor(env)  # episode returns and lengths for TensorBoard and evaluation


def _algo_class(name: str) -> Any:
    import stable_baselines3 as sb3

    return {"dqn": sb3.DQN, "ppo": sb3.PPO, "a2c": sb3.A2C, "sac": sb3.SAC}[name]


def _latest_checkpoint(folder: Path) -> Path | None:
    found = sorted(
        folder.glob("model_*_steps.zip"), key=lambda p: int(re.findall(r"\d+", p.stem)[-1])
    )
    return found[-1] if found else None


def train(cfg: TrainConfig, out_dir: str | Path, progress: bool = True) -> Path:
    """Train the configured agent; returns the path of the saved model."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(
        out / "config.yaml", yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
    )
    torch.set_num_threads(cfg.torch_threads)
    env = make_vec_env(cfg, cfg.n_envs, cfg.seed)
    if cfg.agent == "tabular":
        agent = TabularQAgent(n_actions=int(env.action_space.n), seed=cfg.seed, **cfg.tabular)  # type: ignore[attr-defined]
        from rich.progress import Progress

        with Progress(disable=not progress) as bar:
            task = bar.add_task("tabular episodes", total=cfg.episodes)
            train_tabular(
                agent, env, cfg.episodes, on_episode=lambda n: bar.update(task, completed=n)
            )
        agent.save(out / "model.npz")
        return out / "model.npz"
    from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback

    algo = _algo_class(cfg.agent)
    ckpt_dir = out / "checkpoints"
    latest = _latest_checkpoint(ckpt_dir)
    env = _monitored(env)
    if latest is not None:
        model = algo.load(latest, env=env, device="cpu")
    else:
        model = algo(
            "MlpPolicy",
            env,
            seed=cfg.seed,
            device="cpu",
            tensorboard_log=str(out / "tb"),
            **cfg.hyperparams,
        )
    every = max(1, cfg.eval.every_steps // cfg.n_envs)
    callbacks = [
        CheckpointCallback(save_freq=every, save_path=str(ckpt_dir), name_prefix="model"),
        EvalCallback(
            _monitored(make_vec_env(cfg, 1, cfg.eval.seed)),
            n_eval_episodes=cfg.eval.episodes,
            eval_freq=every,
            best_model_save_path=str(out / "best"),
            log_path=str(out / "eval"),
            deterministic=True,
            verbose=0,
        ),
    ]
    remaining = max(0, cfg.total_steps - int(model.num_timesteps))
    model.learn(
        remaining, callback=callbacks, progress_bar=progress, reset_num_timesteps=latest is None
    )
    model.save(out / "model.zip")
    return out / "model.zip"


class Policy:
    """A saved agent as a κ policy: ``act(obs (N, 9)) -> actions``."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        cfg_file = path.parent / "config.yaml"
        if not cfg_file.is_file():
            raise ConfigError(f"{path}: no config.yaml beside the model")
        self.cfg = load_train_config(cfg_file)
        if path.suffix == ".npz":
            self._tab: TabularQAgent | None = TabularQAgent.load(path)
            self._sb3: Any = None
        else:
            self._tab = None
            self._sb3 = _algo_class(self.cfg.agent).load(path, device="cpu")

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self._tab is not None:
            return self._tab.act(obs, deterministic=True)
        action, _ = self._sb3.predict(obs, deterministic=True)
        return np.asarray(action)
