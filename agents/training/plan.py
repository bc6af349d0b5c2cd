"""Planning a training run: what ``qkf train`` will do in its output folder, decided before any
work and without writing anything (:func:`plan_training`), and how a run goes on from a
checkpoint (:func:`resume_seed`).

``total_steps``: SB3 collects ``n_steps × n_envs`` environment steps per rollout (on-policy:
PPO, A2C) or ``train_freq × n_envs`` between updates (off-policy with ``train_freq`` in steps:
DQN, SAC) and stops only at the end of one, so ``total_steps`` is rounded *up* to a multiple of
that (:func:`rounded_total_steps`): the run trains at least what was asked, and exactly what
``config.yaml`` says.

An output folder that already holds a run (``config.yaml``, checkpoints or a model):

- same config: the run goes on from its newest checkpoint (nothing to do if it is complete);
- a different config: refused, with the fields that differ, unless
  ``force_new`` (the previous run's files are removed, then a new run starts) or
  ``resume`` (it goes on from the newest checkpoint with the new config; only the fields of
  :data:`RESUMABLE` may differ: how long to train, how often to evaluate, torch threads;
  anything else would describe a model the checkpoint was not trained as).

A resumed run is deterministic: resumed twice from the same checkpoint it trains the same model,
bit for bit. It is not identical to an uninterrupted run: its environments start new episodes
from a seed derived from ``(seed, progress)`` (:func:`resume_seed`), and an off-policy agent
starts with an empty replay buffer (checkpoints do not hold it).
"""

from __future__ import annotations

import inspect
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from agents.algorithms import ALGORITHMS, Algorithm, algorithm_class
from agents.config import TrainConfig
from agents.training.records import RUN_FILES, checkpoints, read_json
from qkf.core.config import ConfigError
from qkf.core.io import OutputError, check_output_dir

RESUMABLE = ("total_steps", "episodes", "eval.every_steps", "torch_threads")
"""Config fields ``resume`` may change: they say how long to go on, not what is trained."""


# ----------------------------------------------------------------------------------------------
# total_steps


@dataclass(frozen=True)
class Rollout:
    """What SB3 collects between two updates: ``steps`` environment steps in each of ``n_envs``."""

    algorithm: str
    what: str  # "n_steps" (on-policy) or "train_freq" (off-policy)
    steps: int
    n_envs: int

    @property
    def size(self) -> int:
        return self.steps * self.n_envs

    def describe(self) -> str:
        kind = "rollouts of" if self.what == "n_steps" else "updates every"
        return f"{self.algorithm} {kind} {self.what} {self.steps} × n_envs {self.n_envs}"


def rollout_of(cfg: TrainConfig) -> Rollout | None:
    """The granularity of an SB3 agent's training (None: no SB3 class, or episode-based
    updates)."""
    if not ALGORITHMS[cfg.agent].sb3:
        return None
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

    cls = algorithm_class(cfg.agent)
    if issubclass(cls, OnPolicyAlgorithm):
        what = "n_steps"
    elif issubclass(cls, OffPolicyAlgorithm):
        what = "train_freq"
    else:
        return None
    value = cfg.hyperparams.get(what, _default(cls, what))
    if isinstance(value, list | tuple) and len(value) == 2 and value[1] == "step":
        value = value[0]
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        return None  # episode-based train_freq (or a value the algorithm itself will refuse)
    return Rollout(cls.__name__, what, value, cfg.n_envs)


def _default(cls: Any, name: str) -> Any:
    param = inspect.signature(cls.__init__).parameters.get(name)
    return None if param is None or param.default is inspect.Parameter.empty else param.default


def rounded_total_steps(cfg: TrainConfig) -> tuple[int, Rollout | None]:
    """``total_steps`` rounded up to whole rollouts, and the rollout (None: not rounded)."""
    rollout = rollout_of(cfg)
    if rollout is None:
        return cfg.total_steps, None
    return -(-cfg.total_steps // rollout.size) * rollout.size, rollout


# ----------------------------------------------------------------------------------------------
# planning


@dataclass(frozen=True)
class TrainPlan:
    """What :func:`run_training` will do; :func:`plan_training` makes it without any work."""

    cfg: TrainConfig  # as it will be trained (total_steps rounded)
    out: Path
    source: str  # how messages name the training config
    requested: int  # the budget (total_steps, or the tabular agent's episodes) as asked
    rollout: Rollout | None
    checkpoint: Path | None  # go on from it; None: a new run
    discard: bool  # remove the previous run's files before writing
    complete: bool  # the folder already holds this run, finished: nothing to do
    notes: tuple[str, ...]  # what will be trained, for the user

    @property
    def algorithm(self) -> Algorithm:
        """The registry entry of the agent: its class, model format and progress unit."""
        return ALGORITHMS[self.cfg.agent]

    @property
    def model_path(self) -> Path:
        return self.out / self.algorithm.model_file


def _canonical(cfg: TrainConfig | dict[str, Any]) -> dict[str, Any]:
    """A config as plain JSON data (mapping keys as strings), for comparison."""
    data = cfg.model_dump(mode="json") if isinstance(cfg, TrainConfig) else cfg
    result: dict[str, Any] = json.loads(json.dumps(data, default=str))
    return result


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict) and (data or not prefix):
        flat: dict[str, Any] = {}
        for k, v in data.items():
            flat.update(_flatten(v, f"{prefix}{k}."))
        return flat
    return {prefix[:-1]: data}


_ABSENT = object()


def config_diff(old: dict[str, Any], new: dict[str, Any]) -> list[tuple[str, Any, Any]]:
    """``(dotted.key, old, new)`` for every leaf that differs (absent: a sentinel)."""
    a, b = _flatten(_canonical(old)), _flatten(_canonical(new))
    keys = list(a) + [k for k in b if k not in a]
    return [
        (k, a.get(k, _ABSENT), b.get(k, _ABSENT))
        for k in keys
        if a.get(k, _ABSENT) != b.get(k, _ABSENT)
    ]


def _show(v: Any) -> str:
    return "(absent)" if v is _ABSENT else json.dumps(v, ensure_ascii=False)


def _diff_lines(diffs: list[tuple[str, Any, Any]]) -> str:
    return "\n  ".join(f"{k}: {_show(a)} → {_show(b)}" for k, a, b in diffs)


def _resumable(key: str) -> bool:
    return key in RESUMABLE


def _saved_config(path: Path) -> dict[str, Any] | None:
    """The previous run's config (schema defaults filled in where it still validates)."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, yaml.YAMLError):
        return None
    if not isinstance(data, dict):
        return None
    try:
        return _canonical(TrainConfig.model_validate(data))
    except ValueError:
        return _canonical(data)


def _check_out(out: str | Path) -> None:
    """Refuse an unusable ``--out`` before anything is read or written (an empty path, a file,
    the working, home or project folder, a parent in which nothing can be made)."""
    try:
        check_output_dir(out)
    except OutputError as exc:
        raise ConfigError(f"--out: {exc}") from None


def plan_training(
    cfg: TrainConfig,
    out_dir: str | Path,
    *,
    resume: bool = False,
    force_new: bool = False,
    source: str = "training config",
) -> TrainPlan:
    """Decide what training into ``out_dir`` means; ``ConfigError`` when it cannot go ahead
    (a previous run with another config and neither flag, a change ``resume`` cannot make).
    Reads the folder, writes nothing."""
    if resume and force_new:
        raise ConfigError("--resume and --force-new exclude each other")
    _check_out(out_dir)  # as given: Path("") would be the working directory
    out = Path(out_dir)
    total, rollout = rounded_total_steps(cfg)
    eff = cfg.model_copy(update={"total_steps": total}) if total != cfg.total_steps else cfg
    algo = ALGORITHMS[cfg.agent]
    notes: list[str] = []
    if algo.budget != "total_steps":
        notes.append(
            f"{algo.budget} {getattr(cfg, algo.budget)} ({algo.description}, n_envs {cfg.n_envs})"
        )
    elif rollout is not None and total != cfg.total_steps:
        notes.append(f"total_steps {cfg.total_steps} → {total} ({rollout.describe()})")
    else:
        notes.append(f"total_steps {total}" + (f" ({rollout.describe()})" if rollout else ""))

    def plan(
        checkpoint: Path | None = None, discard: bool = False, complete: bool = False
    ) -> TrainPlan:
        return TrainPlan(
            eff,
            out,
            source,
            getattr(cfg, algo.budget),
            rollout,
            checkpoint,
            discard,
            complete,
            tuple(notes),
        )

    cfg_file = out / "config.yaml"
    ckpts = checkpoints(out / "checkpoints", algo)
    any_ckpts = ckpts or any(checkpoints(out / "checkpoints", ALGORITHMS[a]) for a in ALGORITHMS)
    previous = cfg_file.exists() or bool(any_ckpts) or any((out / n).exists() for n in RUN_FILES)
    if not previous:
        if resume:
            raise ConfigError(
                f"--resume: {out} holds no previous run (no config.yaml, no checkpoints)"
            )
        return plan()
    if force_new:
        notes.append(f"--force-new: the previous run in {out} is discarded")
        return plan(discard=True)

    saved = _saved_config(cfg_file) if cfg_file.exists() else None
    if saved is None:
        if not resume:
            what = "an unreadable config.yaml" if cfg_file.exists() else "no config.yaml"
            raise ConfigError(
                f"{out} holds a previous run with {what}, so it cannot be told whether it was "
                "trained with this config: --resume continues its checkpoints with this config, "
                "--force-new discards it"
            )
        diffs: list[tuple[str, Any, Any]] = []
        notes.append(f"{cfg_file}: missing or unreadable; --resume trusts this config")
    else:
        diffs = config_diff(saved, _canonical(eff))
    if diffs and not resume:
        raise ConfigError(
            f"{out} holds a run trained with another config ({cfg_file}); old → new:\n  "
            f"{_diff_lines(diffs)}\n"
            f"--resume continues it with the new config (only {', '.join(RESUMABLE)} may "
            "change), --force-new discards it and starts over"
        )
    fixed = [d for d in diffs if not _resumable(d[0])]
    if fixed:
        raise ConfigError(
            f"--resume: {out}: only {', '.join(RESUMABLE)} may differ from the config its "
            f"checkpoints were trained with; these differ (old → new):\n  {_diff_lines(fixed)}\n"
            "--force-new discards the run and starts over"
        )
    if diffs:
        notes.append(f"--resume with the changed config:\n  {_diff_lines(diffs)}")

    target, unit = getattr(eff, algo.budget), algo.unit
    info = read_json(out / "training.json") or {}
    model = out / algo.model_file
    done_before = info.get(algo.counter)
    if (
        not diffs
        and saved is not None
        and info.get("complete") is True
        and model.is_file()
        and isinstance(done_before, int)
        and done_before >= target
    ):
        notes.append(
            f"{out} already holds this run, complete ({done_before} {unit}); nothing to train"
        )
        return plan(complete=True)
    if not ckpts:
        if resume:
            notes.append(f"--resume: {out} holds no checkpoint; the run starts from the beginning")
        else:
            notes.append(f"{out} holds an unfinished run without a checkpoint; it starts over")
        return plan(discard=True)
    done, ckpt = ckpts[-1]
    if done >= target and diffs:
        raise ConfigError(
            f"--resume: {algo.budget}: the newest checkpoint ({ckpt.name}) has {done} {unit} "
            f"already; ask for more than {done}, or --force-new to start over"
        )
    notes.append(f"resuming from {ckpt} ({done} of {target} {unit})")
    return plan(checkpoint=ckpt)


# ----------------------------------------------------------------------------------------------
# resuming


def resume_seed(seed: int, progress: int) -> int:
    """Seed of the training environments when a run goes on (fresh episodes, reproducibly)."""
    return int(np.random.SeedSequence([seed, progress]).generate_state(1)[0])
