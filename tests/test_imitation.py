"""Imitation learning (:mod:`agents.imitation`): behavioural cloning and DAgger on a tiny fake
VecEnv whose expert is a known function of the state, the training config's ``env_kwargs`` and
``imitation`` fields, and ``qkf train`` with imitation."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    VecEnv,
    VecFrameStack,
    VecMonitor,
)

from agents.common.vec_env import ScaledReward
from agents.config import ImitationConfig, TrainConfig, load_train_config, validate_train_config
from agents.imitation import DaggerRound, behaviour_clone, dagger, find_expert
from envs import ENV_ID_V4
from envs.transfer_alignment.sb3 import BatchedTransferAlignmentSB3Env
from qkf.core.config import ConfigError
from tests.conftest import TRAINING

EPISODE = 20
MOVES = np.array([[1.0, 0.0], [-0.5, 0.87], [-0.5, -0.87]])  # where each action pushes
W = np.array([[0.3, 1.0], [1.0, -0.4], [-1.0, -0.2]])  # the expert: argmax(W s)


class ToyVecEnv(VecEnv):
    """N episodes of a 2-D state the actions push around: s ← 0.7 s + 0.4 MOVES[a] + noise,
    20 steps each, same-step autoreset. The observation is the state; the expert's action is
    argmax(W s) (Discrete(3)); with ``kind="multi"`` also whether s₀ > 0 (MultiDiscrete
    [3, 2]); with ``kind="box"`` the continuous tanh(W[:2] s) in [-1, 1]²."""

    def __init__(self, num_envs: int, kind: str = "discrete") -> None:
        obs_space = spaces.Box(-10.0, 10.0, (2,), dtype=np.float32)
        action_space: spaces.Space[Any] = {
            "discrete": spaces.Discrete(3),
            "multi": spaces.MultiDiscrete([3, 2]),
            "box": spaces.Box(-1.0, 1.0, (2,), dtype=np.float32),
        }[kind]
        self.render_mode = None
        super().__init__(num_envs, obs_space, action_space)
        self.kind = kind
        self.rng = np.random.default_rng(0)
        self.s = np.zeros((num_envs, 2))
        self.t = np.zeros(num_envs, dtype=int)
        self._actions = np.zeros(num_envs)

    def expert_actions(self) -> np.ndarray:
        best = np.argmax(self.s @ W.T, axis=1)
        if self.kind == "discrete":
            return best
        if self.kind == "multi":
            return np.stack([best, (self.s[:, 0] > 0).astype(int)], axis=1)
        return np.tanh(self.s @ W[:2].T).astype(np.float32)

    def _obs(self) -> np.ndarray:
        return self.s.astype(np.float32)

    def reset(self) -> np.ndarray:
        seeds = [s for s in self._seeds if s is not None]
        if seeds:
            self.rng = np.random.default_rng(seeds[0])
        self._reset_seeds()
        self.s = self.rng.normal(size=self.s.shape)
        self.t[:] = 0
        return self._obs()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> Any:
        a = self._actions
        if self.kind == "multi":
            push = MOVES[a[:, 0].astype(int)]
        elif self.kind == "box":
            push = np.clip(a, -1, 1) @ MOVES[:2]
        else:
            push = MOVES[a.astype(int).reshape(-1)]
        self.s = 0.7 * self.s + 0.4 * push + 0.5 * self.rng.normal(size=self.s.shape)
        self.t += 1
        reward = -np.abs(self.s).sum(axis=1).astype(np.float32)
        done = self.t >= EPISODE
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done):
            infos[i] = {"terminal_observation": self._obs()[i], "TimeLimit.truncated": True}
            self.s[i] = self.rng.normal(size=2)
            self.t[i] = 0
        return self._obs(), reward, done, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self, attr_name)] * self.num_envs

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kw: Any) -> Any:
        return [getattr(self, method_name)(*args, **kw)] * self.num_envs

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * self.num_envs


@pytest.fixture(autouse=True)
def _one_torch_thread() -> Iterator[None]:
    """One thread, as ``qkf train`` runs torch (``torch_threads: 1``): tiny networks on two busy
    cores are many times slower with two."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _ppo(env: VecEnv, seed: int = 0) -> PPO:
    return PPO("MlpPolicy", env, n_steps=32, batch_size=32, seed=seed, device="cpu")


def _expert_data(env: ToyVecEnv, steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """States visited by the expert, labelled with its actions."""
    env.seed(seed)
    obs, acts = [], []
    o = env.reset()
    for _ in range(steps):
        a = env.expert_actions()
        obs.append(o.copy())
        acts.append(a)
        o = env.step(a)[0]  # type: ignore[assignment]
    return np.concatenate(obs), np.concatenate(acts)


def _agreement(model: Any, obs: np.ndarray, acts: np.ndarray) -> float:
    pred, _ = model.predict(obs, deterministic=True)
    return float(np.mean((pred.reshape(len(obs), -1) == acts.reshape(len(obs), -1)).all(axis=1)))


def _params(model: Any) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.policy.parameters()]


# ------------------------------------------------------------------------------------------------
# behavioural cloning


@pytest.mark.parametrize("kind", ["discrete", "multi"])
def test_cloning_expert_data_reaches_the_expert(kind: str) -> None:
    env = ToyVecEnv(8, kind)
    model = _ppo(env)
    obs, acts = _expert_data(env, 250, seed=1)  # 2000 samples
    held_obs, held_acts = _expert_data(env, 60, seed=2)
    before = _agreement(model, held_obs, held_acts)
    losses = behaviour_clone(model, obs, acts, epochs=15, batch_size=64, learning_rate=3e-3, seed=0)
    assert len(losses) == 15
    assert losses[-1] < 0.5 * losses[0]
    after = _agreement(model, held_obs, held_acts)
    assert after >= 0.95 > before


def test_cloning_box_actions() -> None:
    env = ToyVecEnv(8, "box")
    model = _ppo(env)
    obs, acts = _expert_data(env, 250, seed=1)
    held_obs, held_acts = _expert_data(env, 60, seed=2)
    losses = behaviour_clone(model, obs, acts, epochs=15, batch_size=64, learning_rate=3e-3, seed=0)
    assert losses[-1] < losses[0] - 1.0  # the Gaussian's σ shrinks as its mean fits
    pred, _ = model.predict(held_obs, deterministic=True)
    assert np.mean(np.abs(pred - held_acts) <= 0.1) >= 0.9


def test_cloning_is_reproducible_by_seed() -> None:
    env = ToyVecEnv(4)
    obs, acts = _expert_data(env, 50, seed=1)
    runs = []
    for seed in (0, 0, 1):
        model = _ppo(env, seed=0)  # the same initial weights
        behaviour_clone(model, obs, acts, epochs=2, batch_size=32, learning_rate=1e-3, seed=seed)
        runs.append(_params(model))
    assert all(torch.equal(a, b) for a, b in zip(runs[0], runs[1], strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(runs[0], runs[2], strict=True))


def test_recurrent_and_off_policy_models_are_refused() -> None:
    from sb3_contrib import RecurrentPPO

    env = ToyVecEnv(2)
    obs, acts = _expert_data(env, 5, seed=1)
    kw: dict[str, Any] = {"epochs": 1, "batch_size": 4, "learning_rate": 1e-3, "seed": 0}
    recurrent = RecurrentPPO("MlpLstmPolicy", env, n_steps=8, batch_size=8, device="cpu")
    with pytest.raises(ValueError, match="recurrent"):
        behaviour_clone(recurrent, obs, acts, **kw)
    with pytest.raises(ValueError, match="recurrent"):
        dagger(recurrent, env, env.expert_actions, rounds=1, steps_per_round=2, **kw)
    dqn = DQN("MlpPolicy", env, learning_starts=0, device="cpu")
    with pytest.raises(ValueError, match="evaluate_actions"):
        behaviour_clone(dqn, obs, acts, **kw)


# ------------------------------------------------------------------------------------------------
# DAgger


def test_dagger_learns_the_expert_on_its_own_states() -> None:
    env = ToyVecEnv(4)
    env.seed(3)
    model = _ppo(env)
    calls = []

    def expert() -> np.ndarray:
        calls.append(env.t.copy())
        return env.expert_actions()

    rounds = dagger(
        model, env, expert, rounds=4, steps_per_round=100, beta0=0.8, beta_decay=0.5,
        epochs=8, batch_size=64, learning_rate=3e-3, seed=0,
    )  # fmt: skip
    assert all(isinstance(r, DaggerRound) for r in rounds)
    assert [r.round for r in rounds] == [0, 1, 2, 3]
    assert [r.beta for r in rounds] == [0.8 * 0.5**r for r in range(4)]
    assert [r.samples for r in rounds] == [400] * 4  # steps × n_envs
    assert sum(r.samples for r in rounds) == 4 * 100 * 4
    assert len(calls) == 4 * 100 + 1  # after the reset and after every step
    assert rounds[-1].agreement >= 0.9  # the learner, before the last cloning
    assert rounds[-1].loss < rounds[0].loss or rounds[0].loss < 0.2
    # on the learner's own states, fresh episodes
    env.seed(99)
    obs = env.reset()
    agree = []
    for _ in range(50):
        act, _ = model.predict(obs, deterministic=True)
        agree.append(act == env.expert_actions())
        obs = env.step(act)[0]  # type: ignore[assignment]
    assert np.mean(agree) >= 0.95


def test_dagger_is_reproducible() -> None:
    kw: dict[str, Any] = {
        "rounds": 2, "steps_per_round": 10, "beta0": 0.5, "epochs": 2, "batch_size": 16,
        "learning_rate": 1e-3, "seed": 5,
    }  # fmt: skip
    results = []
    for _ in range(2):
        env = ToyVecEnv(2)
        env.seed(0)
        model = _ppo(env)
        rounds = dagger(model, env, env.expert_actions, **kw)
        results.append((rounds, _params(model)))
    assert results[0][0] == results[1][0]
    assert all(torch.equal(a, b) for a, b in zip(results[0][1], results[1][1], strict=True))


def test_find_expert_through_wrappers() -> None:
    env = ToyVecEnv(2)
    wrapped = ScaledReward(VecMonitor(VecFrameStack(env, 2)), 2.0)
    expert = find_expert(wrapped)
    assert expert.__self__ is env  # type: ignore[attr-defined]
    np.testing.assert_array_equal(expert(), env.expert_actions())
    plain = VecMonitor(DummyVecEnv([lambda: _gym_env()]))
    with pytest.raises(ValueError, match="DummyVecEnv has no expert_actions"):
        find_expert(plain)


def _gym_env() -> Any:
    import gymnasium as gym

    return gym.make("CartPole-v1")


# ------------------------------------------------------------------------------------------------
# the training config


def _problems(cfg: TrainConfig) -> str:
    with pytest.raises(ConfigError) as info:
        validate_train_config(cfg, "cfg.yaml", check_scenario=False)
    return str(info.value)


def test_env_kwargs_are_checked_against_the_environment() -> None:
    text = _problems(TrainConfig(agent="ppo", env=ENV_ID_V4, env_kwargs={"contrls": "kappa"}))
    assert "cfg.yaml: env_kwargs.contrls: " in text and "controls, base" in text
    text = _problems(TrainConfig(agent="ppo", env_kwargs={"controls": "kappa"}))
    assert "env_kwargs.controls: " in text and "accepts no env_kwargs" in text
    ok = TrainConfig(agent="ppo", env=ENV_ID_V4, env_kwargs={"controls": "kappa+reset"})
    validate_train_config(ok, "cfg.yaml", check_scenario=False)


def test_env_kwargs_reach_the_environment() -> None:
    from agents.common.vec_env import make_vec_env

    short = ["scenario.duration_s=100"]
    base = TrainConfig(agent="ppo", env=ENV_ID_V4, overrides=short)
    assert make_vec_env(base, 1, 0).action_space == spaces.Discrete(11)  # controls: kappa
    moves = base.model_copy(update={"env_kwargs": {"controls": "kappa+reset"}})
    assert make_vec_env(moves, 1, 0).action_space == spaces.MultiDiscrete([11, 5])
    # values only the environment can judge: a ConfigError naming env_kwargs, not a traceback
    bad = base.model_copy(update={"env_kwargs": {"controls": "bogus"}})
    with pytest.raises(ConfigError, match=r"env_kwargs: qkf/TransferAlignment-v4 refuses .*bogus"):
        make_vec_env(bad, 1, 0)


def test_env_kwargs_from_a_preset_with_set() -> None:
    with pytest.raises(ConfigError, match=r"env_kwargs\.bogus: "):
        load_train_config(str(TRAINING / "train_ppo.yaml"), ["env_kwargs={bogus: 1}"])


@pytest.mark.parametrize(
    ("agent", "needle"),
    [
        ("tabular", "imitation: the tabular agent cannot imitate"),
        ("recurrent_ppo", "imitation: recurrent_ppo keeps an LSTM state"),
        ("dqn", "imitation: dqn's policy has no action likelihood"),
    ],
)
def test_imitation_needs_a_memoryless_actor_critic(agent: str, needle: str) -> None:
    cfg = TrainConfig(agent=agent, env=ENV_ID_V4, imitation={})  # type: ignore[arg-type]
    assert needle in _problems(cfg)


def test_imitation_needs_an_environment_with_an_expert() -> None:
    text = _problems(TrainConfig(agent="ppo", imitation={}))  # type: ignore[arg-type]
    assert "has no expert to imitate" in text
    with pytest.raises(ValueError, match="beta0"):
        TrainConfig(agent="ppo", imitation={"beta0": 1.5})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="then_rel"):
        TrainConfig(agent="ppo", imitation={"then_rel": False})  # type: ignore[arg-type]


def test_imitation_steps_are_environment_steps() -> None:
    cfg = TrainConfig(agent="ppo", imitation={"steps_per_round": 100})  # type: ignore[arg-type]
    assert cfg.imitation is not None
    assert cfg.imitation.vector_steps(8) == 13 and cfg.imitation.vector_steps(1) == 100


# ------------------------------------------------------------------------------------------------
# the runner, on the toy environment


@pytest.mark.parametrize("then_rl", [True, False])
def test_runner_imitates_before_learning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, then_rl: bool
) -> None:
    from agents.common import vec_env
    from agents.training import plan_training, runner
    from agents.training.records import HeldOutEpisodes

    def toy(cfg: Any, n_envs: int, seed: int) -> VecEnv:
        env = ToyVecEnv(n_envs)
        env.seed(seed)
        return env

    monkeypatch.setattr(vec_env, "make_vec_env", toy)
    monkeypatch.setattr(runner, "evaluation_env", lambda cfg: HeldOutEpisodes(toy(cfg, 1, 7), 7))
    cfg = TrainConfig(
        agent="ppo",
        n_envs=2,
        total_steps=64,
        hyperparams={"n_steps": 32, "batch_size": 32, "n_epochs": 1},
        eval={"episodes": 1, "seed": 7, "every_steps": 64},  # type: ignore[arg-type]
        imitation=ImitationConfig(
            rounds=2, steps_per_round=21, epochs=2, batch_size=16, then_rl=then_rl
        ),
    )
    plan = plan_training(cfg, tmp_path / "run")
    path = runner.run(plan, progress=False)
    assert path == tmp_path / "run" / "model.zip" and path.is_file()
    record = json.loads((tmp_path / "run" / "imitation.json").read_text())
    assert record["vector_steps_per_round"] == 11  # 21 environment steps over 2 envs
    assert [r["samples"] for r in record["rounds"]] == [22, 22]
    assert [r["beta"] for r in record["rounds"]] == [1.0, 0.5]
    info = json.loads((tmp_path / "run" / "training.json").read_text())
    assert info["complete"] and info["num_timesteps"] == (64 if then_rl else 0)
    assert (tmp_path / "run" / "checkpoints").is_dir() == then_rl


# ------------------------------------------------------------------------------------------------
# qkf train, on the transfer-alignment environment's expert


@pytest.mark.skipif(
    not hasattr(BatchedTransferAlignmentSB3Env, "expert_actions"),
    reason="the transfer-alignment SB3 environment has no expert_actions() yet",
)
def test_qkf_train_with_imitation(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from qkf.cli import app

    out = tmp_path / "run"
    sets = [
        f"env={ENV_ID_V4}", "n_envs=2", "overrides=[scenario.duration_s=100]",
        "hyperparams={n_steps: 16, batch_size: 16, n_epochs: 1}",
        "eval={episodes: 1, seed: 100000, every_steps: 32}", "total_steps=32",
        "env_kwargs={expert: nis-rule}",
        "imitation={rounds: 2, steps_per_round: 16, epochs: 2, batch_size: 16}",
    ]  # fmt: skip
    args = ["train", str(TRAINING / "train_ppo.yaml"), "--out", str(out), "--quiet"]
    result = CliRunner().invoke(app, [*args, *(a for s in sets for a in ("--set", s))])
    assert result.exit_code == 0, result.output
    record = json.loads((out / "imitation.json").read_text())
    assert [r["samples"] for r in record["rounds"]] == [16, 16]
    assert all(0.0 <= r["agreement"] <= 1.0 for r in record["rounds"])
    assert (out / "model.zip").is_file()
