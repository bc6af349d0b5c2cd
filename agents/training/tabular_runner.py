"""The tabular runner: trains :class:`agents.tabular.TabularQAgent` on a plan (:mod:`.plan`),
with the same records as an SB3 run (:mod:`.records`): checkpoints
``model_<episodes>_episodes.npz`` and evaluations on the held-out episodes at the end of the
episode that crosses each ``eval.every_steps`` mark (no episode is cut short), the best model,
``training.json`` and a TensorBoard log of each episode's return, ε and the number of states
visited.

The agent trains until ``episodes`` episodes have ended; its environments run in parallel, so
the last step may end a few more (``training.json`` says how many).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from agents.common.vec_env import make_vec_env
from agents.tabular import TabularQAgent, train_tabular
from agents.training.plan import TrainPlan, resume_seed
from agents.training.records import (
    BEST,
    CHECKPOINTS,
    EvaluationHistory,
    RecordSchedule,
    RunInfo,
    evaluate,
    evaluation_env,
    write_best,
)


def run_tabular(plan: TrainPlan, progress: bool) -> Path:
    """Train the plan's tabular agent; returns the path of the saved model."""
    from rich.progress import Progress
    from tensorboard.summary import Writer

    cfg, out = plan.cfg, plan.out
    if plan.checkpoint is not None:
        agent = TabularQAgent.load(plan.checkpoint)
        env = make_vec_env(cfg, cfg.n_envs, resume_seed(cfg.seed, agent.episodes))
    else:
        env = make_vec_env(cfg, cfg.n_envs, cfg.seed)
        n_actions = int(env.action_space.n)  # type: ignore[attr-defined]
        agent = TabularQAgent(n_actions=n_actions, seed=cfg.seed, **cfg.tabular)
    resumed = plan.checkpoint is not None
    info = RunInfo(out, plan.checkpoint)
    history = EvaluationHistory.resumed(out, agent.steps) if resumed else EvaluationHistory()
    held_out = evaluation_env(cfg)
    schedule = RecordSchedule(cfg.eval.every_steps, agent.steps, resumed)
    plan.begin_run(
        info,
        {
            "agent": cfg.agent,
            "algorithm": "TabularQAgent",
            "episodes_requested": cfg.episodes,
            "episodes": agent.episodes,
            "num_timesteps": agent.steps,
        },
    )
    writer = Writer(str(out / "tb" / "tabular"))

    def record() -> None:
        """Checkpoint, evaluate (best model), log; once per step count."""
        steps = agent.steps
        if schedule.take(steps):
            name = plan.algorithm.checkpoint_name(agent.episodes)
            agent.save(out / CHECKPOINTS / name)
            returns, lengths = evaluate(agent, held_out)
            new_best = history.add(steps, returns, lengths)
            history.write(out)
            if new_best:
                agent.save(out / BEST / "best_model.npz")
                write_best(out, steps, history.best, name)
            info.write(checkpoint=name)
            writer.add_scalar("eval/mean_reward", float(returns.mean()), steps)
            writer.add_scalar("eval/mean_ep_length", float(lengths.mean()), steps)
            writer.flush()
        info.write(episodes=agent.episodes, num_timesteps=agent.steps)

    def on_step(finished: list[float]) -> None:
        for ret in finished:
            writer.add_scalar("rollout/ep_return", ret, agent.steps)
        if finished:
            writer.add_scalar("train/epsilon", agent.epsilon(), agent.steps)
            writer.add_scalar("train/states_visited", agent.states_visited, agent.steps)
            writer.add_scalar("train/episodes", agent.episodes, agent.steps)
        if finished and schedule.due(agent.steps):  # at an episode end: none is cut short
            record()

    try:
        with Progress(disable=not progress) as bar:
            task = bar.add_task("tabular episodes", total=cfg.episodes, completed=agent.episodes)
            start = agent.episodes
            remaining = cfg.episodes - agent.episodes
            if remaining > 0:

                def on_episode(n: int) -> Any:
                    return bar.update(task, completed=start + n)

                train_tabular(agent, env, remaining, on_episode=on_episode, on_step=on_step)
        record()
    finally:
        writer.close()
    agent.save(plan.model_path)
    info.write(
        episodes=agent.episodes,
        num_timesteps=agent.steps,
        complete=True,
        model=plan.model_path.name,
    )
    return plan.model_path
