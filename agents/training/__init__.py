"""Training of agents that choose κ: Stable-Baselines3 models and the tabular agent
(``qkf train``; docs/environment.md, "Training and evaluation").

The training config is :class:`agents.config.TrainConfig`. A run is planned first
(:func:`plan_training`: no work, nothing written), then carried out (:func:`run_training`);
:func:`train` does both. By concern:

- :mod:`.plan`: what a run into a folder means (new, resumed, complete, refused), ``total_steps``
  rounded to whole rollouts, the seed of a resumed run;
- :mod:`.records`: checkpoints, evaluations on held-out episodes, the best model,
  ``training.json``: the output folder's files, each written atomically;
- :mod:`.runner`: trains any agent of the algorithm registry (SB3's algorithms, and the tabular
  agent, which keeps SB3's model contract), with SB3's own checkpoint and evaluation callbacks;
- the environments, from the config's ``env`` in :data:`envs.ENVIRONMENTS`:
  :mod:`agents.common.vec_env`.

The output folder holds one run:

- ``config.yaml``: the config as trained (``total_steps`` as actually trained);
- ``training.json``: what was trained (steps or episodes asked for and done, the rollout that
  rounded ``total_steps``, the checkpoints resumed from) and whether the run is ``complete``;
- ``model.zip`` (SB3) or ``model.npz`` (tabular), the final model;
- ``checkpoints/``, ``eval/evaluations.npz``, ``best/`` (:mod:`.records`);
- ``tb/``: TensorBoard logs (SB3's own; the tabular agent logs each episode's return, before
  the learner's reward scaling, ε and the number of states visited, and the evaluations).

Training is deterministic by seed: the same config and seed train the same model, bit for bit,
on the same software; so does a run resumed from the same checkpoint.
"""

from __future__ import annotations

from pathlib import Path

from agents.common.vec_env import ScaledReward, make_vec_env
from agents.config import TrainConfig
from agents.training.plan import (
    RESUMABLE,
    Rollout,
    TrainPlan,
    config_diff,
    plan_training,
    rollout_of,
    rounded_total_steps,
)
from agents.training.records import RUN_DIRS, RUN_FILES, checkpoints
from agents.training.runner import run


def run_training(plan: TrainPlan, progress: bool = True) -> Path:
    """Carry out a plan; returns the path of the saved model. Hyperparameter values that the
    SB3 algorithm refuses raise ``ConfigError`` before anything is written."""
    if plan.complete:
        return plan.model_path
    return run(plan, progress)


def train(
    cfg: TrainConfig,
    out_dir: str | Path,
    progress: bool = True,
    *,
    resume: bool = False,
    force_new: bool = False,
) -> Path:
    """Plan and train the configured agent; returns the path of the saved model."""
    return run_training(plan_training(cfg, out_dir, resume=resume, force_new=force_new), progress)


__all__ = [
    "RESUMABLE",
    "RUN_DIRS",
    "RUN_FILES",
    "Rollout",
    "ScaledReward",  # agents.training.ScaledReward: the name RL Zoo3 configs saved with runs use
    "TrainPlan",
    "checkpoints",
    "config_diff",
    "make_vec_env",
    "plan_training",
    "rollout_of",
    "rounded_total_steps",
    "run_training",
    "train",
]
