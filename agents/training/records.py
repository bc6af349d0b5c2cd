"""The records of a training run: checkpoints, evaluations on held-out episodes, the best model
and ``training.json``, what the runner (:mod:`.runner`) keeps.

- ``checkpoints/model_<steps>_steps.zip`` (SB3) or ``model_<episodes>_episodes.npz``
  (tabular): what a run resumes from (:func:`checkpoints` lists them);
- ``eval/evaluations.npz`` (``timesteps``, ``results``, ``ep_lengths``: SB3's ``EvalCallback``
  format): the greedy returns and lengths of ``eval.episodes`` episodes on the held-out seeds
  ``eval.seed + i``, the same episodes at every evaluation (:class:`HeldOutEpisodes`), in the
  order they ended (SB3's ``evaluate_policy``); a resumed run keeps those up to its checkpoint
  (:class:`EvaluationHistory`);
- ``best/best_model.zip`` or ``.npz`` and ``best/best.json``: the model of the best evaluation;
- ``training.json`` (:class:`RunInfo`): what was trained, the checkpoints resumed from and
  whether the run is ``complete``.

Every file is written atomically: by :func:`qkf.core.io.atomic_write_bytes`, or, where a
Stable-Baselines3 callback writes it, into a staging folder first and then renamed into place
(:func:`publish_staged`), so an interrupted run never leaves a truncated checkpoint that a
resume would pick up.
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from agents.algorithms import Algorithm
from agents.common.vec_env import make_vec_env
from qkf.core.io import atomic_write_bytes, atomic_write_text

if TYPE_CHECKING:
    from agents.config import TrainConfig

RUN_FILES = ("config.yaml", "training.json", "model.zip", "model.npz", "imitation.json")
RUN_DIRS = ("checkpoints", "eval", "best", "tb")
"""What a run writes into its folder (and ``force_new`` removes; nothing else is touched)."""
CHECKPOINTS = "checkpoints"
EVALUATIONS = Path("eval") / "evaluations.npz"
BEST = "best"
STAGING = ".staging"
"""The folder, inside ``checkpoints/``, ``eval/`` and ``best/``, where SB3's callbacks write
before their files are renamed into place."""


def checkpoint_progress(path: Path, algo: Algorithm) -> int:
    """The progress a checkpoint of ``algo`` was saved at (in ``algo.unit``)."""
    progress = algo.checkpoint_progress(path.name)
    if progress is None:
        raise ValueError(f"{path}: not a checkpoint name ({algo.checkpoint_name(0)})")
    return progress


def checkpoints(folder: Path, algo: Algorithm) -> list[tuple[int, Path]]:
    """``(progress, path)`` of the checkpoints of ``algo`` in ``folder``, oldest first."""
    found = []
    if folder.is_dir():
        for p in folder.iterdir():
            progress = algo.checkpoint_progress(p.name)
            if progress is not None and p.is_file():
                found.append((progress, p))
    return sorted(found)


def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON object from ``path``; None if it is missing, unreadable or not an object."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def fresh_staging(folder: Path) -> Path:
    """``folder``'s staging folder, emptied of what an interrupted run may have left there."""
    staging = folder / STAGING
    shutil.rmtree(staging, ignore_errors=True)
    return staging


def publish_staged(folder: Path) -> list[str]:
    """Move every file that a callback wrote into ``folder/.staging`` into ``folder``: flushed
    to disk, then renamed over the old file (one atomic step); returns their names."""
    staging = folder / STAGING
    names = []
    for staged in sorted(staging.iterdir()) if staging.is_dir() else []:
        if not staged.is_file():
            continue
        fd = os.open(staged, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(staged, folder / staged.name)
        names.append(staged.name)
    return names


def remove_staging(out: Path) -> None:
    """Remove the (empty) staging folders of a finished run."""
    for folder in (out / CHECKPOINTS, out / EVALUATIONS.parent, out / BEST):
        shutil.rmtree(folder / STAGING, ignore_errors=True)


class RecordSchedule:
    """When a run records (checkpoint and evaluation): at the first chance at or after every
    ``every`` environment steps, and at the end; at most once per step count, so a resumed run
    does not record again the step it was resumed at (``start``)."""

    def __init__(self, every: int, start: int, resumed: bool) -> None:
        self.every = every
        self.next_due = (start // every + 1) * every
        self.last = start if resumed else -1  # the step count recorded last

    def due(self, steps: int) -> bool:
        """Whether a record is due at ``steps`` (a chance to record: between two updates)."""
        return steps >= self.next_due

    def take(self, steps: int) -> bool:
        """Claim the record at ``steps``: False if it was taken already."""
        if steps == self.last:
            return False
        self.last = steps
        self.next_due = (steps // self.every + 1) * self.every
        return True


# ----------------------------------------------------------------------------------------------
# training.json


class RunInfo:
    """``training.json``: fields written so far (each write rewrites the file atomically) and
    the checkpoints the run was resumed from, oldest first; and the run's first and last writes
    (:meth:`begin`, :meth:`finish`)."""

    def __init__(self, out: Path, checkpoint: Path | None) -> None:
        self.out = out
        self.path = out / "training.json"
        # read before the run's first write replaces the file
        previous = read_json(self.path) or {}
        resumed = previous.get("resumed_from") if checkpoint is not None else None
        self.resumed_from: list[str] = list(resumed) if isinstance(resumed, list) else []
        if checkpoint is not None:
            self.resumed_from.append(checkpoint.name)
        self.fields: dict[str, Any] = {}

    def write(self, **fields: Any) -> None:
        """Add or update ``fields`` and rewrite the file."""
        self.fields.update(fields)
        self.fields["resumed_from"] = self.resumed_from
        atomic_write_text(self.path, json.dumps(self.fields, indent=2, ensure_ascii=False) + "\n")

    def begin(self, cfg: TrainConfig, *, discard: bool, fields: dict[str, Any]) -> None:
        """The first writes of a run: the previous run's files go (``discard``; nothing else
        in the folder is touched), then the config as trained and a first ``training.json``
        (``complete: false``)."""
        if discard:
            for name in RUN_FILES:
                (self.out / name).unlink(missing_ok=True)
            for name in RUN_DIRS:
                shutil.rmtree(self.out / name, ignore_errors=True)
        self.out.mkdir(parents=True, exist_ok=True)
        text = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False, allow_unicode=True)
        atomic_write_text(self.out / "config.yaml", text)
        self.write(**fields, complete=False)

    def finish(self, model: Any, path: Path, **fields: Any) -> None:
        """The last writes of a run: the model (``model.save`` into memory, then one atomic
        write to ``path``), then ``training.json`` with ``complete: true``."""
        buf = io.BytesIO()
        model.save(buf)
        atomic_write_bytes(path, buf.getvalue())
        self.write(**fields, complete=True, model=path.name)


# ----------------------------------------------------------------------------------------------
# evaluations


class HeldOutEpisodes(VecEnvWrapper):
    """The evaluation environment: every ``reset`` reseeds sub-environment ``i`` with
    ``seed + i``, so every evaluation (one reset each, in SB3's ``evaluate_policy``) plays the
    same held-out episodes and evaluations at different steps compare like with like."""

    def __init__(self, venv: VecEnv, seed: int) -> None:
        super().__init__(venv)
        self.held_out_seed = seed

    def reset(self) -> Any:
        self.venv.seed(self.held_out_seed)
        return self.venv.reset()

    def step_wait(self) -> Any:
        return self.venv.step_wait()


def evaluation_env(cfg: TrainConfig) -> HeldOutEpisodes:
    """``eval.episodes`` episodes of the config's environment on the seeds ``eval.seed + i``,
    apart from training's ``seed + i``; the learner's reward scale does not apply."""
    return HeldOutEpisodes(make_vec_env(cfg, cfg.eval.episodes, cfg.eval.seed), cfg.eval.seed)


@dataclass
class EvaluationHistory:
    """The evaluations of a run (``eval/evaluations.npz``) and its best mean return so far."""

    timesteps: list[int] = field(default_factory=list)
    results: list[np.ndarray] = field(default_factory=list)
    lengths: list[np.ndarray] = field(default_factory=list)
    best: float = -math.inf

    @classmethod
    def resumed(cls, out: Path, start: int) -> EvaluationHistory:
        """The evaluations up to the checkpoint at ``start`` resumed from (later ones, if any,
        belong to training that is being redone), and the best model if it is one of them
        (``best/`` is removed otherwise)."""
        history = cls()
        path = out / EVALUATIONS
        if path.is_file():
            try:
                with np.load(path) as z:
                    keep = z["timesteps"] <= start
                    history.timesteps = [int(t) for t in z["timesteps"][keep]]
                    history.results = list(z["results"][keep])
                    history.lengths = list(z["ep_lengths"][keep])
            except (OSError, KeyError, ValueError):
                history = cls()
        best = read_json(out / BEST / "best.json") or {}
        score = best.get("mean_reward")
        if (
            isinstance(best.get("timestep"), int)
            and best["timestep"] <= start
            and isinstance(score, int | float)
        ):
            history.best = float(score)
        else:
            shutil.rmtree(out / BEST, ignore_errors=True)
        return history


def write_best(out: Path, step: int, mean: float, checkpoint: str) -> None:
    """``best/best.json``: when the best model was evaluated, its mean return, its checkpoint."""
    best = {"timestep": step, "mean_reward": mean, "checkpoint": checkpoint}
    atomic_write_text(out / BEST / "best.json", json.dumps(best, indent=2) + "\n")
