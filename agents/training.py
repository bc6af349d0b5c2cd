"""Training of agents that choose κ: Stable-Baselines3 models and the tabular agent.

The training config is :class:`agents.config.TrainConfig`.

``train`` writes the model (``model.zip`` or ``model.npz``) and the config it used into the
output folder, TensorBoard logs under ``tb/``, checkpoints under ``checkpoints/`` (SB3), and
resumes from the newest checkpoint when one is there.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from agents.algorithms import algorithm_class
from agents.common.vec_env import TransferAlignmentVecEnv
from agents.config import TrainConfig
from agents.tabular import TabularQAgent, train_tabular
from qkf.core.io import atomic_write_text


def make_vec_env(cfg: TrainConfig, n_envs: int, seed: int) -> TransferAlignmentVecEnv:
    env = TransferAlignmentVecEnv(
        n_envs,
        cfg.scenario,
        cfg.action_type,
        cfg.reward,
        overrides=list(cfg.overrides),
        period_s=cfg.period_s,
    )
    env.seed(seed)
    return env


def _monitored(env: TransferAlignmentVecEnv) -> Any:
    from stable_baselines3.common.vec_env import VecMonitor

    return VecMonitor(env)  # episode returns and lengths for TensorBoard and evaluation


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
    import torch  # only training needs it

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

    algo = algorithm_class(cfg.agent)
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
