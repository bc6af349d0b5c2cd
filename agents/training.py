"""Training of agents that choose κ: Stable-Baselines3 models and the tabular agent.

The training config is :class:`agents.config.TrainConfig`. A run is planned first
(:func:`plan_training`: no work, nothing written), then carried out (:func:`run_training`);
:func:`train` does both.

The output folder holds one run:

- ``config.yaml``: the config as trained (``total_steps`` as actually trained, see below);
- ``training.json``: what was trained (steps or episodes asked for and done, the rollout that
  rounded ``total_steps``, the checkpoints resumed from) and whether the run is ``complete``;
- ``model.zip`` (SB3) or ``model.npz`` (tabular), the final model;
- ``checkpoints/``: ``model_<steps>_steps.zip`` (SB3) or ``model_<episodes>_episodes.npz``
  (tabular), saved every ``eval.every_steps`` environment steps (at the end of the rollout or,
  tabular, of the episode that crosses the mark) and at the end;
- ``eval/evaluations.npz`` (``timesteps``, ``results``, ``ep_lengths``, as SB3's
  ``EvalCallback``): greedy returns and lengths of ``eval.episodes`` episodes on the held-out
  seeds ``eval.seed + i``, the same episodes at every evaluation, taken with each checkpoint;
  ``best/best_model.zip`` or ``.npz`` (and ``best.json``): the model of the best evaluation;
- ``tb/``: TensorBoard logs (SB3's own; the tabular agent logs each episode's return, ε and the
  number of states visited, and the evaluations).

Every file is written atomically.

``total_steps``: SB3 collects ``n_steps × n_envs`` environment steps per rollout (on-policy:
PPO, A2C) or ``train_freq × n_envs`` between updates (off-policy with ``train_freq`` in steps:
DQN, SAC) and stops only at the end of one, so ``total_steps`` is rounded *up* to a multiple of
that: the run trains at least what was asked, and exactly what ``config.yaml`` says.

An output folder that already holds a run (``config.yaml``, checkpoints or a model):

- same config: the run goes on from its newest checkpoint (nothing to do if it is complete);
- a different config: refused, with the fields that differ, unless
  ``force_new`` (the previous run's files are removed, then a new run starts) or
  ``resume`` (it goes on from the newest checkpoint with the new config; only the fields of
  :data:`RESUMABLE` may differ: how long to train, how often to evaluate, torch threads;
  anything else would describe a model the checkpoint was not trained as).

The tabular agent trains until ``episodes`` episodes have ended; its environments run in
parallel, so the last step may end a few more (``training.json`` says how many).

A resumed run is reproducible but not identical to an uninterrupted one: its environments
start new episodes from a seed derived from ``(seed, progress)``, and an off-policy agent
starts with an empty replay buffer.
"""

from __future__ import annotations

import inspect
import io
import json
import math
import os
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvWrapper

from agents.algorithms import ALGORITHMS, algorithm_class
from agents.common.vec_env import TransferAlignmentVecEnv
from agents.config import HEADER, TrainConfig
from agents.tabular import TabularQAgent, train_tabular
from envs import TA_ENV_OBSERVATIONS
from qkf.core.config import ConfigError
from qkf.core.io import OutputError, atomic_write_bytes, atomic_write_text, check_output_dir

RESUMABLE = ("total_steps", "episodes", "eval.every_steps", "torch_threads")
"""Config fields ``resume`` may change: they say how long to go on, not what is trained."""

RUN_FILES = ("config.yaml", "training.json", "model.zip", "model.npz")
RUN_DIRS = ("checkpoints", "eval", "best", "tb")
"""What a run writes into its folder (and ``force_new`` removes; nothing else is touched)."""

_CKPT = {
    "sb3": re.compile(r"^model_(\d+)_steps\.zip$"),
    "tabular": re.compile(r"^model_(\d+)_episodes\.npz$"),
}


def make_vec_env(cfg: TrainConfig, n_envs: int, seed: int) -> VecEnv:
    if cfg.env not in TA_ENV_OBSERVATIONS:  # another environment: DummyVecEnv over gym.make
        return _gym_vec_env(cfg, n_envs, seed)
    env = TransferAlignmentVecEnv(
        n_envs,
        cfg.scenario,
        cfg.action_type,
        cfg.reward,
        overrides=list(cfg.overrides),
        period_s=cfg.period_s,
        observation=TA_ENV_OBSERVATIONS[cfg.env],
    )
    env.seed(seed)
    return env


def _gym_vec_env(cfg: TrainConfig, n_envs: int, seed: int) -> VecEnv:
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    kwargs: dict[str, Any] = {
        "scenario": cfg.scenario,
        "action_type": cfg.action_type,
        "reward": cfg.reward,
        "overrides": list(cfg.overrides),
        "period_s": cfg.period_s,
    }
    env = DummyVecEnv([lambda: gym.make(cfg.env, **kwargs) for _ in range(n_envs)])
    env.seed(seed)
    return env


class ScaledReward(VecEnvWrapper):
    """Rewards times a constant for the learner (``reward_scale``); the monitor beneath and the
    evaluations see the reward as defined. A fixed factor keeps training deterministic and
    resumable, unlike running reward normalisation."""

    def __init__(self, venv: VecEnv, scale: float) -> None:
        super().__init__(venv)
        self.scale = scale

    def reset(self) -> Any:
        return self.venv.reset()

    def step_wait(self) -> Any:
        obs, reward, done, infos = self.venv.step_wait()
        return obs, reward * self.scale, done, infos


def _monitored(env: VecEnv) -> Any:
    from stable_baselines3.common.vec_env import VecMonitor

    return VecMonitor(env)  # episode returns and lengths for TensorBoard


def _is_tabular(cfg: TrainConfig) -> bool:
    return ALGORITHMS[cfg.agent].load is None


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
    """The granularity of an SB3 agent's training (None: tabular, or episode-based updates)."""
    if _is_tabular(cfg):
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
    requested_steps: int  # total_steps as asked
    rollout: Rollout | None
    checkpoint: Path | None  # go on from it; None: a new run
    discard: bool  # remove the previous run's files before writing
    complete: bool  # the folder already holds this run, finished: nothing to do
    notes: tuple[str, ...]  # what will be trained, for the user

    @property
    def tabular(self) -> bool:
        return _is_tabular(self.cfg)

    @property
    def model_path(self) -> Path:
        return self.out / ("model.npz" if self.tabular else "model.zip")


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


def checkpoints(folder: Path, tabular: bool) -> list[tuple[int, Path]]:
    """``(progress, path)`` of the checkpoints in ``folder``, oldest first (progress: SB3
    environment steps, tabular episodes)."""
    pattern = _CKPT["tabular" if tabular else "sb3"]
    found = []
    if folder.is_dir():
        for p in folder.iterdir():
            m = pattern.match(p.name)
            if m and p.is_file():
                found.append((int(m.group(1)), p))
    return sorted(found)


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


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
    tabular = _is_tabular(cfg)
    notes: list[str] = []
    if tabular:
        notes.append(f"episodes {cfg.episodes} (tabular Q-learning, n_envs {cfg.n_envs})")
    elif rollout is not None and total != cfg.total_steps:
        notes.append(f"total_steps {cfg.total_steps} → {total} ({rollout.describe()})")
    else:
        notes.append(f"total_steps {total}" + (f" ({rollout.describe()})" if rollout else ""))

    def plan(
        checkpoint: Path | None = None, discard: bool = False, complete: bool = False
    ) -> TrainPlan:
        return TrainPlan(
            eff, out, source, cfg.total_steps, rollout, checkpoint, discard, complete, tuple(notes)
        )

    cfg_file = out / "config.yaml"
    ckpts = checkpoints(out / "checkpoints", tabular)
    any_ckpts = ckpts or checkpoints(out / "checkpoints", not tabular)
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

    target, unit = (eff.episodes, "episodes") if tabular else (eff.total_steps, "steps")
    info = _read_json(out / "training.json") or {}
    model = out / ("model.npz" if tabular else "model.zip")
    done_before = info.get("episodes" if tabular else "num_timesteps")
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
        key = "episodes" if tabular else "total_steps"
        raise ConfigError(
            f"--resume: {key}: the newest checkpoint ({ckpt.name}) has {done} {unit} already; "
            f"ask for more than {done}, or --force-new to start over"
        )
    notes.append(f"resuming from {ckpt} ({done} of {target} {unit})")
    return plan(checkpoint=ckpt)


# ----------------------------------------------------------------------------------------------
# the run's records: checkpoints, evaluations, best model, training.json


def evaluate(
    act: Callable[[np.ndarray], Any], env: Any, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Returns and lengths of the first episode of each of ``env``'s environments, seeded with
    ``seed`` (so every evaluation sees the same episodes), actions from ``act(obs)``."""
    env.seed(seed)
    obs = env.reset()
    n = env.num_envs
    returns, lengths = np.zeros(n), np.zeros(n, dtype=np.int64)
    active = np.ones(n, dtype=bool)
    while active.any():
        obs, reward, done, _ = env.step(np.asarray(act(obs)))
        returns[active] += reward[active]
        lengths[active] += 1
        active &= ~np.asarray(done, dtype=bool)
    return returns, lengths


class _Records:
    """Checkpoints, evaluations (``eval/evaluations.npz``), the best model and
    ``training.json`` of one run. ``steps``: environment steps trained so far."""

    def __init__(
        self,
        plan: TrainPlan,
        start_steps: int,
        save: Callable[[Path], None],
        act: Callable[[np.ndarray], Any],
        ckpt_name: Callable[[], str],
    ) -> None:
        self.plan, self.save, self.act, self.ckpt_name = plan, save, act, ckpt_name
        cfg = plan.cfg
        self.every = cfg.eval.every_steps
        self.next_due = (start_steps // self.every + 1) * self.every
        self.last = start_steps if plan.checkpoint is not None else -1
        self.eval_env = make_vec_env(cfg, cfg.eval.episodes, cfg.eval.seed)
        self.ext = ".npz" if plan.tabular else ".zip"
        self.timesteps: list[int] = []
        self.results: list[np.ndarray] = []
        self.lengths: list[np.ndarray] = []
        self.best = -math.inf
        prev = _read_json(plan.out / "training.json") or {}
        resumed = prev.get("resumed_from") if plan.checkpoint is not None else None
        self.resumed_from: list[str] = list(resumed) if isinstance(resumed, list) else []
        if plan.checkpoint is not None:
            self.resumed_from.append(plan.checkpoint.name)
            self._load_previous(start_steps)
        self.info: dict[str, Any] = {}

    def _load_previous(self, start: int) -> None:
        """Keep the evaluations up to the checkpoint resumed from (later ones, if any, belong
        to training that is being redone)."""
        path = self.plan.out / "eval" / "evaluations.npz"
        if path.is_file():
            try:
                with np.load(path) as z:
                    keep = z["timesteps"] <= start
                    self.timesteps = [int(t) for t in z["timesteps"][keep]]
                    self.results = list(z["results"][keep])
                    self.lengths = list(z["ep_lengths"][keep])
            except (OSError, KeyError, ValueError):
                self.timesteps, self.results, self.lengths = [], [], []
        best = _read_json(self.plan.out / "best" / "best.json") or {}
        score = best.get("mean_reward")
        if (
            isinstance(best.get("timestep"), int)
            and best["timestep"] <= start
            and isinstance(score, int | float)
        ):
            self.best = float(score)
        else:
            shutil.rmtree(self.plan.out / "best", ignore_errors=True)

    def due(self, steps: int) -> bool:
        return steps >= self.next_due

    def record(self, steps: int) -> tuple[float, float] | None:
        """Checkpoint and evaluate at ``steps`` (once per step count); the evaluation's mean
        return and episode length."""
        if steps == self.last:
            return None
        self.last = steps
        self.next_due = (steps // self.every + 1) * self.every
        name = self.ckpt_name()
        self.save(self.plan.out / "checkpoints" / name)
        returns, lengths = evaluate(self.act, self.eval_env, self.plan.cfg.eval.seed)
        self.timesteps.append(steps)
        self.results.append(returns)
        self.lengths.append(lengths)
        buf = io.BytesIO()
        np.savez(
            buf,
            timesteps=np.array(self.timesteps, dtype=np.int64),
            results=np.array(self.results),
            ep_lengths=np.array(self.lengths),
        )
        atomic_write_bytes(self.plan.out / "eval" / "evaluations.npz", buf.getvalue())
        mean = float(np.mean(returns))
        if mean > self.best:
            self.best = mean
            self.save(self.plan.out / "best" / f"best_model{self.ext}")
            best = {"timestep": steps, "mean_reward": mean, "checkpoint": name}
            atomic_write_text(
                self.plan.out / "best" / "best.json", json.dumps(best, indent=2) + "\n"
            )
        self.write_info(checkpoint=name)
        return mean, float(np.mean(lengths))

    def write_info(self, **fields: Any) -> None:
        self.info.update(fields)
        self.info["resumed_from"] = self.resumed_from
        atomic_write_text(
            self.plan.out / "training.json",
            json.dumps(self.info, indent=2, ensure_ascii=False) + "\n",
        )


def _begin(plan: TrainPlan, info: dict[str, Any], records: _Records) -> None:
    """The first writes of a run: the previous run's files go (if asked), then the config."""
    out = plan.out
    if plan.discard:
        for name in RUN_FILES:
            (out / name).unlink(missing_ok=True)
        for name in RUN_DIRS:
            shutil.rmtree(out / name, ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(plan.cfg.model_dump(mode="json"), sort_keys=False, allow_unicode=True)
    atomic_write_text(out / "config.yaml", text)
    records.write_info(**info, complete=False)


def _resume_seed(seed: int, progress: int) -> int:
    """Seed of the training environments when a run goes on (fresh episodes, reproducibly)."""
    return int(np.random.SeedSequence([seed, progress]).generate_state(1)[0])


# ----------------------------------------------------------------------------------------------
# running


def run_training(plan: TrainPlan, progress: bool = True) -> Path:
    """Carry out a plan; returns the path of the saved model. Hyperparameter values that the
    SB3 algorithm refuses raise ``ConfigError`` before anything is written."""
    if plan.complete:
        return plan.model_path
    import torch  # the SB3 VecEnv has loaded it already

    torch.set_num_threads(plan.cfg.torch_threads)
    if plan.tabular:
        return _run_tabular(plan, progress)
    return _run_sb3(plan, progress)


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


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _run_sb3(plan: TrainPlan, progress: bool) -> Path:
    from stable_baselines3.common.callbacks import BaseCallback

    cfg, out = plan.cfg, plan.out
    algo = algorithm_class(cfg.agent)
    ckpt_steps = 0
    if plan.checkpoint is not None:
        ckpt_steps = int(_CKPT["sb3"].match(plan.checkpoint.name).group(1))  # type: ignore[union-attr]
    seed = cfg.seed if plan.checkpoint is None else _resume_seed(cfg.seed, ckpt_steps)
    env = _monitored(make_vec_env(cfg, cfg.n_envs, seed))
    if cfg.reward_scale != 1.0:
        env = ScaledReward(env, cfg.reward_scale)
    if plan.checkpoint is not None:
        model = algo.load(plan.checkpoint, env=env, device="cpu", tensorboard_log=str(out / "tb"))
        model.set_random_seed(seed)  # torch, numpy and the environments: a reproducible resume
    else:
        try:
            model = algo(
                "MlpPolicy",
                env,
                seed=cfg.seed,
                device="cpu",
                tensorboard_log=str(out / "tb"),
                **cfg.hyperparams,
            )
        except (TypeError, ValueError, AssertionError) as exc:
            raise ConfigError(
                f"{HEADER}\n  {plan.source}: hyperparams: {algo.__name__} refuses them: "
                f"{_one_line(exc)}"
            ) from None

    def save(path: Path) -> None:
        buf = io.BytesIO()
        model.save(buf)
        atomic_write_bytes(path, buf.getvalue())

    records = _Records(
        plan,
        int(model.num_timesteps),
        save,
        lambda obs: model.predict(obs, deterministic=True)[0],
        lambda: f"model_{int(model.num_timesteps)}_steps.zip",
    )
    info: dict[str, Any] = {
        "agent": cfg.agent,
        "algorithm": algo.__name__,
        "total_steps_requested": plan.requested_steps,
        "total_steps": cfg.total_steps,
        "rounding": plan.rollout.describe() if plan.rollout is not None else None,
        "num_timesteps": int(model.num_timesteps),
    }
    _begin(plan, info, records)

    class Records(BaseCallback):
        """Checkpoint and evaluate between updates (after one, before the next rollout)."""

        def _on_step(self) -> bool:
            return True

        def _on_rollout_start(self) -> None:
            if records.due(self.num_timesteps):
                self._record()

        def _on_training_end(self) -> None:
            self._record()

        def _record(self) -> None:
            stats = records.record(self.num_timesteps)
            if stats is not None:
                self.logger.record("eval/mean_reward", stats[0])
                self.logger.record("eval/mean_ep_length", stats[1])
                self.logger.dump(self.num_timesteps)
            records.write_info(num_timesteps=int(self.num_timesteps))

    remaining = max(0, cfg.total_steps - int(model.num_timesteps))
    started = time.perf_counter()
    model.learn(
        remaining,
        callback=Records(),
        progress_bar=progress,
        reset_num_timesteps=plan.checkpoint is None,
    )
    save(out / "model.zip")
    records.write_info(
        num_timesteps=int(model.num_timesteps),
        complete=True,
        model="model.zip",
        wall_s=round(time.perf_counter() - started, 1),  # this session's, on os.cpu_count() cores
        cpu_count=os.cpu_count(),
    )
    return out / "model.zip"


def _run_tabular(plan: TrainPlan, progress: bool) -> Path:
    from rich.progress import Progress
    from tensorboard.summary import Writer

    cfg, out = plan.cfg, plan.out
    if plan.checkpoint is not None:
        agent = TabularQAgent.load(plan.checkpoint)
        env = make_vec_env(cfg, cfg.n_envs, _resume_seed(cfg.seed, agent.episodes))
    else:
        env = make_vec_env(cfg, cfg.n_envs, cfg.seed)
        agent = TabularQAgent(n_actions=int(env.action_space.n), seed=cfg.seed, **cfg.tabular)  # type: ignore[attr-defined]
    records = _Records(
        plan,
        agent.steps,
        agent.save,
        lambda obs: agent.act(obs, deterministic=True),
        lambda: f"model_{agent.episodes}_episodes.npz",
    )
    info: dict[str, Any] = {
        "agent": cfg.agent,
        "algorithm": "TabularQAgent",
        "episodes_requested": cfg.episodes,
        "episodes": agent.episodes,
        "num_timesteps": agent.steps,
    }
    _begin(plan, info, records)
    writer = Writer(str(out / "tb" / "tabular"))

    def on_step(finished: list[float]) -> None:
        for ret in finished:
            writer.add_scalar("rollout/ep_return", ret, agent.steps)
        if finished:
            writer.add_scalar("train/epsilon", agent.epsilon(), agent.steps)
            writer.add_scalar("train/states_visited", agent.states_visited, agent.steps)
            writer.add_scalar("train/episodes", agent.episodes, agent.steps)
        if finished and records.due(agent.steps):  # at an episode end: no episode cut short
            _record()

    def _record() -> None:
        stats = records.record(agent.steps)
        if stats is not None:
            writer.add_scalar("eval/mean_reward", stats[0], agent.steps)
            writer.add_scalar("eval/mean_ep_length", stats[1], agent.steps)
            writer.flush()
        records.write_info(episodes=agent.episodes, num_timesteps=agent.steps)

    try:
        with Progress(disable=not progress) as bar:
            task = bar.add_task("tabular episodes", total=cfg.episodes, completed=agent.episodes)
            start = agent.episodes
            remaining = cfg.episodes - agent.episodes
            if remaining > 0:
                train_tabular(
                    agent,
                    env,
                    remaining,
                    on_episode=lambda n: bar.update(task, completed=start + n),
                    on_step=on_step,
                )
        _record()
    finally:
        writer.close()
    agent.save(out / "model.npz")
    records.write_info(
        episodes=agent.episodes, num_timesteps=agent.steps, complete=True, model="model.npz"
    )
    return out / "model.npz"
