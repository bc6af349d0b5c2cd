"""The training runner: trains the plan's agent (:mod:`.plan`), an SB3 algorithm or the tabular
agent, which keeps SB3's model contract (:mod:`agents.tabular`), with SB3's own callbacks for
what they do, and the project's records (:mod:`.records`) for what they do not. What differs
between agents comes from the algorithm registry (:data:`agents.algorithms.ALGORITHMS`): the
constructor's arguments, the model's format, and what ``learn`` counts (steps, or the tabular
agent's episodes), which also names its checkpoints (``model_<episodes>_episodes.npz``).

SB3 does the work: ``CheckpointCallback`` saves ``checkpoints/model_<steps>_steps.zip``,
``EvalCallback`` evaluates on the held-out episodes, logs ``eval/mean_reward`` and
``eval/mean_ep_length``, keeps ``eval/evaluations.npz`` and the best model, and a
``CallbackList`` runs them in turn. The project adds:

- *when* they run (:class:`BetweenUpdates`): between two updates, at the first rollout start at
  or after every ``eval.every_steps`` steps, and at the end. A checkpoint saved there is a clean
  point to resume from (the rollout buffer, which it does not hold, is empty); for the tabular
  agent a rollout ends with an episode, so none is cut short;
- atomic files: the callbacks write into staging folders, then every file is renamed into place
  (:func:`~agents.training.records.publish_staged`), so an interrupted save never leaves a
  truncated checkpoint for a resume to pick up;
- held-out episodes that are the same at every evaluation
  (:class:`~agents.training.records.HeldOutEpisodes`), the evaluations and best model of the run
  a resume continues, ``best/best.json`` and ``training.json``;
- reward scaling for the learner (:class:`~agents.common.vec_env.ScaledReward`) and a
  deterministic resume (:func:`~agents.training.plan.resume_seed`);
- ``torch_threads`` for torch's intra-op pool (SB3 has loaded torch already);
- imitation first (``imitation:``): DAgger from the environment's expert
  (:func:`agents.imitation.dagger`) on the training environment before ``model.learn``, its
  rounds in ``imitation.json``; a resumed run does not imitate again (its checkpoint holds the
  result), and ``then_rl: false`` saves the cloned policy as the model without learning.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
import warnings
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    CheckpointCallback,
    EvalCallback,
    EventCallback,
)
from stable_baselines3.common.vec_env import VecEnv

from agents.algorithms import Algorithm, algorithm_class
from agents.common.vec_env import learner_env
from agents.config import HEADER
from agents.training.plan import TrainPlan, resume_seed
from agents.training.records import (
    BEST,
    CHECKPOINTS,
    EVALUATIONS,
    EvaluationHistory,
    HeldOutEpisodes,
    RecordSchedule,
    RunInfo,
    checkpoint_progress,
    evaluation_env,
    fresh_staging,
    publish_staged,
    remove_staging,
    write_best,
)
from qkf.core.config import ConfigError
from qkf.core.io import atomic_write_text

IMITATION = "imitation.json"
"""The DAgger rounds of a run with ``imitation:`` (:class:`agents.imitation.DaggerRound`)."""


class BetweenUpdates(EventCallback):
    """Fires its callback when the schedule says a record is due, between two updates of the
    model (at a rollout start), and at the end of training.

    Not SB3's ``EveryNTimesteps``, which fires after an environment step, inside a rollout: a
    checkpoint taken there misses the half-collected rollout (checkpoints do not hold it), and
    the evaluations would fall on other models than those of the runs trained so far (the
    zoo's ``evaluations.npz``, from which its shipped seeds were chosen).
    """

    def __init__(self, schedule: RecordSchedule, callback: BaseCallback) -> None:
        super().__init__(callback)
        self.schedule = schedule

    def _on_rollout_start(self) -> None:
        if self.schedule.due(int(self.model.num_timesteps)):
            self._fire()

    def _on_training_end(self) -> None:
        self._fire()

    def _fire(self) -> None:
        if self.schedule.take(int(self.model.num_timesteps)):
            self._on_event()


class AtomicCheckpoint(CheckpointCallback):
    """SB3's ``CheckpointCallback`` (``save_freq=1``: a checkpoint whenever it is called,
    :class:`BetweenUpdates` decides when), named by the algorithm (SB3's
    ``model_<steps>_steps.zip``, or its counterpart in the algorithm's unit), its file written
    into a staging folder and then renamed into ``folder``."""

    def __init__(self, folder: Path, algorithm: Algorithm) -> None:
        super().__init__(save_freq=1, save_path=str(fresh_staging(folder)), name_prefix="model")
        self.folder = folder
        self.algorithm = algorithm
        self.last_saved: str | None = None  # the name of the newest checkpoint

    def _checkpoint_path(self, checkpoint_type: str = "", extension: str = "") -> str:
        if checkpoint_type:  # a replay buffer or VecNormalize (not saved here): SB3's name
            return super()._checkpoint_path(checkpoint_type, extension)
        progress = int(getattr(self.model, self.algorithm.counter))
        return os.path.join(self.save_path, self.algorithm.checkpoint_name(progress))

    def _on_step(self) -> bool:
        go_on = super()._on_step()
        for name in publish_staged(self.folder):
            self.last_saved = name
        return go_on


class HeldOutEvaluation(EvalCallback):
    """SB3's ``EvalCallback`` (``eval_freq=1``: an evaluation whenever it is called) on the
    held-out episodes, continuing the evaluations and the best model of ``history``; its
    ``evaluations.npz`` and ``best_model.zip`` written into staging folders, then renamed into
    ``eval/`` and ``best/``, and ``best/best.json`` written beside a new best model."""

    def __init__(
        self,
        out: Path,
        env: HeldOutEpisodes,
        history: EvaluationHistory,
        checkpoint: AtomicCheckpoint,
    ) -> None:
        super().__init__(
            env,
            n_eval_episodes=env.num_envs,  # one episode per held-out seed
            eval_freq=1,
            log_path=str(fresh_staging(out / EVALUATIONS.parent)),
            best_model_save_path=str(fresh_staging(out / BEST)),
            deterministic=True,
            verbose=0,
            warn=False,  # the returns are summed by evaluate_policy, not read from a Monitor
        )
        self.out = out
        self.checkpoint = checkpoint
        self.evaluations_timesteps = list(history.timesteps)
        self.evaluations_results = [r.tolist() for r in history.results]
        self.evaluations_length = [n.tolist() for n in history.lengths]
        self.best_mean_reward = history.best

    def _init_callback(self) -> None:
        with warnings.catch_warnings():
            # SB3 compares the outermost wrappers only: the training env is the same
            # environment under a monitor (and the learner's reward scale), the evaluation env
            # under HeldOutEpisodes, on purpose
            warnings.filterwarnings("ignore", message="Training and eval env are not of the same")
            super()._init_callback()

    def _on_step(self) -> bool:
        best_before = self.best_mean_reward
        go_on = super()._on_step()
        publish_staged(self.out / EVALUATIONS.parent)
        publish_staged(self.out / BEST)
        if self.best_mean_reward > best_before:
            write_best(
                self.out,
                self.num_timesteps,
                self.best_mean_reward,
                self.checkpoint.last_saved or "",
            )
        return go_on


class RecordProgress(BaseCallback):
    """``training.json`` after each record: the newest checkpoint and the progress made."""

    def __init__(self, info: RunInfo, checkpoint: AtomicCheckpoint) -> None:
        super().__init__()
        self.info = info
        self.checkpoint = checkpoint

    def _on_step(self) -> bool:
        self.info.write(
            checkpoint=self.checkpoint.last_saved,
            **_progress(self.model, self.checkpoint.algorithm),
        )
        return True


def _progress(model: Any, algorithm: Algorithm) -> dict[str, int]:
    """What ``training.json`` says of the progress made: the steps, and the algorithm's own
    counter (the tabular agent's episodes)."""
    counted = int(getattr(model, algorithm.counter))
    return {"num_timesteps": int(model.num_timesteps), algorithm.counter: counted}


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _build(plan: TrainPlan, algo: Any, env: VecEnv, seed: int) -> Any:
    """The model of class ``algo``: loaded from the plan's checkpoint, or new, built with the
    config's settings for it (``hyperparams``, or ``tabular``); ``ConfigError`` for values the
    algorithm refuses (nothing has been written yet)."""
    cfg, out, algorithm = plan.cfg, plan.out, plan.algorithm
    if plan.checkpoint is not None:
        model = algo.load(plan.checkpoint, env=env, device="cpu", tensorboard_log=str(out / "tb"))
        model.set_random_seed(seed)  # torch, numpy and the environments: a reproducible resume
        return model
    policy = () if algorithm.policy is None else (algorithm.policy,)
    settings = getattr(cfg, algorithm.settings)
    try:
        return algo(
            *policy,
            env=env,
            seed=cfg.seed,
            device="cpu",
            tensorboard_log=str(out / "tb"),
            **settings,
        )
    except (TypeError, ValueError, AssertionError) as exc:
        raise ConfigError(
            f"{HEADER}\n  {plan.source}: {algorithm.settings}: {algo.__name__} refuses them: "
            f"{_one_line(exc)}"
        ) from None


def _imitate(plan: TrainPlan, model: Any, env: VecEnv) -> None:
    """DAgger from the environment's expert on the training environment (``imitation:``);
    its rounds written to ``OUT/imitation.json``."""
    from agents.imitation import dagger, find_expert

    cfg = plan.cfg
    im = cfg.imitation
    assert im is not None
    started = time.perf_counter()
    rounds = dagger(
        model,
        env,
        find_expert(env),
        rounds=im.rounds,
        steps_per_round=im.vector_steps(env.num_envs),
        beta0=im.beta0,
        beta_decay=im.beta_decay,
        epochs=im.epochs,
        batch_size=im.batch_size,
        learning_rate=im.learning_rate,
        seed=cfg.seed,
    )
    record = {
        "algorithm": "dagger",
        "n_envs": env.num_envs,
        "vector_steps_per_round": im.vector_steps(env.num_envs),
        "rounds": [dataclasses.asdict(r) for r in rounds],
        "wall_s": round(time.perf_counter() - started, 1),
    }
    atomic_write_text(plan.out / IMITATION, json.dumps(record, indent=2) + "\n")


def run(plan: TrainPlan, progress: bool) -> Path:
    """Train the plan's agent; returns the path of the saved model."""
    import torch  # SB3 has loaded it already

    torch.set_num_threads(plan.cfg.torch_threads)
    cfg, out, algorithm = plan.cfg, plan.out, plan.algorithm
    algo = algorithm_class(cfg.agent)
    seed = cfg.seed
    if plan.checkpoint is not None:  # new episodes, drawn reproducibly from the progress made
        seed = resume_seed(cfg.seed, checkpoint_progress(plan.checkpoint, algorithm))
    env = learner_env(cfg, seed)
    model = _build(plan, algo, env, seed)
    start = int(model.num_timesteps)
    resumed = plan.checkpoint is not None
    info = RunInfo(out, plan.checkpoint)
    history = EvaluationHistory.resumed(out, start) if resumed else EvaluationHistory()
    held_out = evaluation_env(cfg)
    target = int(getattr(cfg, algorithm.budget))
    info.begin(
        cfg,
        discard=plan.discard,
        fields={
            "agent": cfg.agent,
            "algorithm": algo.__name__,
            f"{algorithm.budget}_requested": plan.requested,
            # the tabular agent's budget field is also its counter (episodes, never rounded):
            # there it says the episodes done, which _progress writes
            **({} if algorithm.budget == algorithm.counter else {algorithm.budget: target}),
            "rounding": plan.rollout.describe() if plan.rollout is not None else None,
            **_progress(model, algorithm),
        },
    )
    checkpoint = AtomicCheckpoint(out / CHECKPOINTS, algorithm)
    records = CallbackList(
        [
            checkpoint,
            HeldOutEvaluation(out, held_out, history, checkpoint),
            RecordProgress(info, checkpoint),
        ]
    )
    schedule = RecordSchedule(cfg.eval.every_steps, start, resumed)
    started = time.perf_counter()
    if cfg.imitation is not None and not resumed:
        _imitate(plan, model, env)
    if cfg.imitation is None or cfg.imitation.then_rl:
        model.learn(
            max(0, target - int(getattr(model, algorithm.counter))),
            callback=BetweenUpdates(schedule, records),
            progress_bar=progress,
            reset_num_timesteps=not resumed,
        )
    info.finish(
        model,
        plan.model_path,
        wall_s=round(time.perf_counter() - started, 1),  # this session's, on os.cpu_count() cores
        cpu_count=os.cpu_count(),
        **_progress(model, algorithm),
    )
    remove_staging(out)
    return plan.model_path
