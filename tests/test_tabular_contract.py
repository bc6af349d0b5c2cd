"""The tabular agent keeps Stable-Baselines3's model contract, so the one training runner serves
it (agents/training/runner.py): its constructor and ``load`` take SB3's arguments, ``learn``
calls SB3 callbacks at SB3's points (a rollout ending with an episode), ``save`` names files as
SB3 does; without a callback it imports neither SB3 nor torch."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from agents.tabular import TabularQAgent
from tests.conftest import ROOT


class StaggeredEpisodes(VecEnv):
    """Episodes of ``lengths[i]`` steps in sub-environment i (same-step autoreset, SB3's
    ``terminal_observation``); the observation is the step within the episode, the reward 1."""

    def __init__(self, lengths: tuple[int, ...], n_actions: int = 3) -> None:
        obs_space = spaces.Box(0.0, 100.0, (1,), dtype=np.float32)
        super().__init__(len(lengths), obs_space, spaces.Discrete(n_actions))
        self.lengths = np.array(lengths)
        self.t = np.zeros(len(lengths), dtype=int)
        self.seeded: list[int | None] = []

    def reset(self) -> np.ndarray:
        self.seeded = list(self._seeds)
        self._reset_seeds()
        self.t[:] = 0
        return self.t[:, None].astype(np.float32)

    def step_async(self, actions: np.ndarray) -> None:
        pass

    def step_wait(self) -> Any:
        self.t += 1
        done = self.t >= self.lengths
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done):
            infos[i] = {"terminal_observation": np.array([self.t[i]], np.float32)}
            self.t[i] = 0
        return self.t[:, None].astype(np.float32), np.ones(self.num_envs), done, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [None] * self.num_envs

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        pass

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kw: Any) -> list[Any]:
        return [None] * self.num_envs

    def env_is_wrapped(self, wrapper_class: Any, indices: Any = None) -> list[bool]:
        return [False] * self.num_envs


class Hooks(BaseCallback):
    """Records at which step count each of SB3's hooks was called."""

    def __init__(self, stop_after: int | None = None) -> None:
        super().__init__()
        self.calls: dict[str, list[int]] = {}
        self.stop_after = stop_after

    def _note(self, hook: str) -> None:
        self.calls.setdefault(hook, []).append(int(self.model.num_timesteps))

    def _on_training_start(self) -> None:
        self._note("training_start")

    def _on_rollout_start(self) -> None:
        self._note("rollout_start")

    def _on_step(self) -> bool:
        self._note("step")
        return self.stop_after is None or self.n_calls < self.stop_after

    def _on_rollout_end(self) -> None:
        self._note("rollout_end")

    def _on_training_end(self) -> None:
        self._note("training_end")


def test_learn_calls_sb3_callbacks_with_rollouts_ending_at_episode_ends() -> None:
    # episodes of 3 and 5 steps in two environments end at steps 3 (1), 5 (2), 6 (3), 9 (4):
    # 4 episodes take 9 vector steps of 2 environment steps
    agent = TabularQAgent(env=StaggeredEpisodes((3, 5)), bins={0: [0.5, 1.5, 2.5]}, seed=1)
    hooks = Hooks()
    agent.learn(4, callback=hooks)
    assert agent.episodes == 4 and agent.num_timesteps == 18
    assert hooks.calls["training_start"] == [0] and hooks.calls["training_end"] == [18]
    assert hooks.calls["step"] == [2 * k for k in range(1, 10)]
    assert hooks.calls["rollout_start"] == [0, 6, 10, 12]
    assert hooks.calls["rollout_end"] == [6, 10, 12, 18]
    assert hooks.model is agent and agent.logger is not None  # SB3's logger, for callbacks
    assert {"new_obs", "rewards", "dones", "infos"} <= hooks.locals.keys()  # SB3's names


def test_a_callback_that_returns_false_stops_learning() -> None:
    agent = TabularQAgent(env=StaggeredEpisodes((3, 5)), bins={0: [0.5]})
    hooks = Hooks(stop_after=4)
    agent.learn(100, callback=[hooks])  # a list: SB3's CallbackList
    assert hooks.calls["step"] == [2, 4, 6, 8] and agent.num_timesteps == 8
    assert agent.episodes == 1 and hooks.calls["training_end"] == [8]  # ended at step 3


def test_a_second_learn_goes_on_from_where_the_first_stopped_unless_it_resets() -> None:
    # SB3 resets the environment only when reset_num_timesteps or on the first call: episodes
    # of 5 steps, 2 learned, then 1 more goes on from step 2 of the running episodes
    env = StaggeredEpisodes((5, 7))
    agent = TabularQAgent(env=env, bins={0: [0.5]}, seed=2)
    agent.learn(1)
    assert agent.num_timesteps == 10 and env.t.tolist() == [0, 5]
    agent.learn(1, reset_num_timesteps=False)  # sub-env 1 ends its episode at its step 7
    assert agent.num_timesteps == 14 and env.t.tolist() == [2, 0]
    agent.learn(1)  # resets: 5 more steps
    assert agent.num_timesteps == 24 and env.t.tolist() == [0, 5]
    agent.set_env(env)  # a new env: the next learn starts new episodes even without a reset
    agent.learn(1, reset_num_timesteps=False)
    assert agent.num_timesteps == 34


class ScaledMonitor(StaggeredEpisodes):
    """Rewards × 0.5, the unscaled return in ``info["episode"]`` (a ``VecMonitor`` below a
    reward scaling, as the training runner stacks them)."""

    def step_wait(self) -> Any:
        obs, rewards, done, infos = super().step_wait()
        for i in np.flatnonzero(done):
            infos[i]["episode"] = {"r": float(self.lengths[i]), "l": int(self.lengths[i])}
        return obs, 0.5 * rewards, done, infos


def test_the_logged_return_is_the_monitors_unscaled_one(tmp_path: Path) -> None:
    from stable_baselines3.common.logger import Logger

    seen: list[float] = []

    class Recorder(Logger):
        def record(self, key: str, value: Any, exclude: Any = None) -> None:
            if key == "rollout/ep_return":
                seen.append(float(value))

    class Swap(BaseCallback):  # learn sets up SB3's logger; the recorder replaces it
        def _on_training_start(self) -> None:
            self.model.logger = Recorder(None, [])

        def _on_step(self) -> bool:
            return True

    agent = TabularQAgent(env=ScaledMonitor((3, 4)), bins={0: [0.5]})
    agent.learn(3, callback=Swap())
    assert seen == [3.0, 4.0, 3.0]  # the lengths, not the learner's 1.5, 2.0, 1.5


def test_sb3_constructor_load_save_and_env() -> None:
    env = StaggeredEpisodes((2, 2), n_actions=4)
    agent = TabularQAgent(env=env, bins={0: [0.5]}, seed=5)
    assert agent.n_actions == 4 and agent.get_env() is env
    assert agent.get_vec_normalize_env() is None
    agent.learn(6)
    buf = io.BytesIO()
    agent.save(buf)  # SB3's save into a file object
    buf.seek(0)
    other = StaggeredEpisodes((2, 2), n_actions=4)
    copy = TabularQAgent.load(buf, env=other, device="cpu")
    np.testing.assert_array_equal(copy.table, agent.table)
    assert copy.get_env() is other and copy.episodes == agent.episodes
    assert copy.num_timesteps == agent.num_timesteps
    np.testing.assert_array_equal(copy.visits, agent.visits)
    assert copy.rng.bit_generator.state == agent.rng.bit_generator.state
    copy.set_random_seed(17)  # SB3's: seeds the environment
    other.reset()
    assert other.seeded == [17, 18]
    with pytest.raises(ValueError, match="n_actions: 4, but the env has 3 actions"):
        copy.set_env(StaggeredEpisodes((2, 2), n_actions=3))
    with pytest.raises(ValueError, match=r"^n_actions: needed"):
        TabularQAgent()
    with pytest.raises(ValueError, match=r"^device: the tabular agent runs on the CPU"):
        TabularQAgent(n_actions=2, device="cuda")
    with pytest.raises(ValueError, match=r"^env: the agent has no environment"):
        TabularQAgent(n_actions=2).learn(1)


def test_save_adds_the_suffix_as_sb3_does(tmp_path: Path) -> None:
    agent = TabularQAgent(n_actions=3)
    agent.save(tmp_path / "best_model")  # what SB3's EvalCallback asks for
    assert [p.name for p in tmp_path.iterdir()] == ["best_model.npz"]
    assert TabularQAgent.load(tmp_path / "best_model.npz").n_actions == 3


def test_learning_without_a_callback_imports_neither_sb3_nor_torch() -> None:
    code = """
import sys
import numpy as np
from gymnasium import spaces
from agents.tabular import TabularQAgent

class Steps:  # an SB3 VecEnv by duck typing, without SB3
    num_envs = 2
    action_space = spaces.Discrete(3)
    def reset(self):
        self.t = np.zeros(2)
        return self.t[:, None]
    def step(self, actions):
        self.t += 1
        done = self.t >= 4
        infos = [{"terminal_observation": self.t[i:i + 1].copy()} if done[i] else {}
                 for i in range(2)]
        self.t[done] = 0
        return self.t[:, None], np.ones(2), done, infos

agent = TabularQAgent(env=Steps(), bins={0: [1.5]}).learn(4)
assert agent.episodes == 4, agent.episodes
print(sorted(m for m in ("torch", "stable_baselines3") if m in sys.modules))
"""
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == "[]"
