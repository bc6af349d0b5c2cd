"""Agents: the tabular learner, the SB3 VecEnv adapter, a tiny SB3 training run, saved policies."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from agents.config import load_train_config
from agents.policy import Policy
from agents.tabular import TabularQAgent
from agents.training import train
from envs import TransferAlignmentEnv
from envs.transfer_alignment.sb3 import BatchedTransferAlignmentSB3Env
from qkf.cli import app
from qkf.transfer_alignment.config import ConfigError
from tests.conftest import CONFIGS, TRAINING

SHORT = ["scenario.duration_s=200"]


def test_vec_env_matches_single_env_and_autoresets() -> None:
    vec = BatchedTransferAlignmentSB3Env(2, overrides=SHORT)
    vec.seed(5)
    obs = vec.reset()
    singles = [TransferAlignmentEnv(overrides=SHORT) for _ in range(2)]
    ref = np.stack([e.reset(seed=5 + i)[0] for i, e in enumerate(singles)])
    np.testing.assert_array_equal(obs, ref)
    for step in range(20):  # 20 periods of 10 s end the episode
        o, r, done, infos = vec.step(np.array([3, 7]))
        so = [e.step(a) for e, a in zip(singles, (3, 7), strict=True)]
        np.testing.assert_array_equal(r, np.array([x[1] for x in so], dtype=np.float32))
        if step < 19:
            np.testing.assert_array_equal(o, np.stack([x[0] for x in so]))
            assert not done.any()
    assert done.all()
    np.testing.assert_array_equal(infos[0]["terminal_observation"], so[0][0])
    assert infos[0]["TimeLimit.truncated"] is True


def test_tabular_agent_learns_deterministically_and_round_trips(tmp_path: Path) -> None:
    def run() -> TabularQAgent:
        env = BatchedTransferAlignmentSB3Env(4, overrides=SHORT)
        env.seed(0)
        agent = TabularQAgent(env=env, seed=3)  # n_actions from the env, as SB3's constructors
        assert agent.learn(8) is agent and agent.n_actions == 11
        assert agent.episodes == 8 and agent.num_timesteps == 8 * 20  # 4 envs, 2 episodes each
        assert np.all(np.isfinite(agent.table))
        return agent

    a, b = run(), run()
    np.testing.assert_array_equal(a.table, b.table)
    assert np.count_nonzero(a.table) > 0
    a.save(tmp_path / "q.npz")
    c = TabularQAgent.load(tmp_path / "q.npz")
    np.testing.assert_array_equal(c.table, a.table)
    assert c.bins == a.bins and c.episodes == a.episodes == 8
    obs = np.random.default_rng(0).normal(size=(50, 9)).astype(np.float32)
    np.testing.assert_array_equal(c.act(obs), a.act(obs))
    # the exploration stream continues where it stopped
    np.testing.assert_array_equal(c.act(obs, deterministic=False), a.act(obs, deterministic=False))


def test_tabular_update_by_hand() -> None:
    agent = TabularQAgent(n_actions=3, bins={0: [0.0]}, alpha=0.5, gamma=0.9)
    s_neg, s_pos = np.array([[-1.0] + [0.0] * 8]), np.array([[1.0] + [0.0] * 8])
    agent.table[agent.state(s_pos)[0]] = [0.0, 2.0, 1.0]
    agent.update(s_neg, np.array([1]), np.array([1.0]), s_pos, np.array([False]))
    assert agent.table[agent.state(s_neg)[0], 1] == pytest.approx(0.5 * (1.0 + 0.9 * 2.0))
    agent.update(s_neg, np.array([2]), np.array([1.0]), s_pos, np.array([True]))
    assert agent.table[agent.state(s_neg)[0], 2] == pytest.approx(0.5)


def test_tiny_ppo_training_saves_and_reloads(tmp_path: Path) -> None:
    cfg = load_train_config(
        TRAINING / "train_ppo.yaml",
        [
            "total_steps=256",
            "n_envs=4",
            "overrides=[scenario.duration_s=200]",
            "hyperparams={n_steps: 32, batch_size: 32, n_epochs: 1}",
            "eval={episodes: 1, seed: 100000, every_steps: 128}",
        ],
    )
    path = train(cfg, tmp_path, progress=False)
    assert path.name == "model.zip" and (tmp_path / "config.yaml").exists()
    assert list((tmp_path / "checkpoints").glob("model_*_steps.zip"))
    assert list((tmp_path / "tb").iterdir())
    obs = np.random.default_rng(1).normal(size=(20, 9)).astype(np.float32)
    first = Policy(path).act(obs)
    np.testing.assert_array_equal(Policy(path).act(obs), first)
    assert first.shape == (20,) and set(first.tolist()) <= set(range(11))


def test_train_config_errors() -> None:
    with pytest.raises(ConfigError, match="sac needs continuous"):
        load_train_config(TRAINING / "train_sac.yaml", ["action_type=discrete"])
    with pytest.raises(ConfigError, match="invalid training config"):
        load_train_config(TRAINING / "train_ppo.yaml", ["agent=nope"])


def test_train_command_tabular(tmp_path: Path) -> None:
    result = CliRunner().invoke(
        app,
        [
            "train",
            str(TRAINING / "train_tabular.yaml"),
            "--out",
            str(tmp_path),
            "--quiet",
            "--set",
            "episodes=4",
            "--set",
            "n_envs=4",
            "--set",
            "overrides=[scenario.duration_s=200]",
        ],
    )
    assert result.exit_code == 0, result.output
    assert (tmp_path / "model.npz").exists()
    assert Policy(tmp_path / "model.npz").act(np.zeros((2, 9), np.float32)).shape == (2,)
    # judged on a config of another action set: refused before any work, as an SB3 zip is
    out = tmp_path / "bench"
    result = CliRunner().invoke(
        app,
        ["bench", "thermal_snap", "--methods", f"policy:{tmp_path / 'model.npz'}", "--trials",
         "2", "--set", "scenario.duration_s=200", "--set", "adaptive.actions.count=5",
         "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 2, result.output
    assert "chooses among 11 actions" in result.output and "has 5" in result.output
    assert not out.exists()


@pytest.mark.slow  # trains an agent, then benchmarks and evaluates it
def test_policy_in_bench_and_evaluate(tmp_path: Path) -> None:
    runner = CliRunner()
    sets = [
        "--set",
        "episodes=4",
        "--set",
        "n_envs=4",
        "--set",
        "overrides=[scenario.duration_s=200]",
    ]
    res = runner.invoke(
        app,
        [
            "train",
            str(TRAINING / "train_tabular.yaml"),
            "--out",
            str(tmp_path / "m"),
            "--quiet",
            *sets,
        ],
    )
    assert res.exit_code == 0, res.output
    model = tmp_path / "m" / "model.npz"
    res = runner.invoke(
        app,
        [
            "bench",
            str(CONFIGS / "paper.yaml"),
            "--methods",
            f"kf,policy:{model}",
            "--trials",
            "3",
            "--set",
            "scenario.duration_s=200",
            "--out",
            str(tmp_path / "b"),
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    summary = (tmp_path / "b" / "summary.csv").read_text().splitlines()
    # a model saved as model.npz is named after its folder
    assert summary[2].startswith("policy:m,3,0,")
    kappa = (tmp_path / "b" / "kappa.csv").read_text()
    assert "policy:m," in kappa
    res = runner.invoke(
        app,
        [
            "evaluate",
            str(model),
            "--trials",
            "2",
            "--set",
            "scenario.duration_s=200",
            "--out",
            str(tmp_path / "e"),
            "--quiet",
        ],
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "e" / "rms.csv").exists()
    # the table reads on its own: kf beside the policy (kf-tuned only where its tuning is
    # cached; the suite runs without the results cache)
    rows = (tmp_path / "e" / "summary.csv").read_text().splitlines()[1:]
    assert [r.split(",")[0] for r in rows] == ["kf", "policy:m"]


@pytest.mark.parametrize("name", ["train_a2c", "train_sac", "train_dqn", "train_ppo_continuous"])
def test_every_shipped_sb3_config_trains_a_few_steps(name: str, tmp_path: Path) -> None:
    cfg = load_train_config(
        TRAINING / f"{name}.yaml",
        [
            "total_steps=64",
            "n_envs=2",
            "overrides=[scenario.duration_s=100]",
            "eval={episodes: 1, seed: 100000, every_steps: 64}",
        ],
    )
    hyper = dict(cfg.hyperparams)
    if cfg.agent in ("sac", "dqn"):
        hyper.update(learning_starts=8, batch_size=8)
    if cfg.agent == "ppo":
        hyper.update(n_steps=16, batch_size=16)
    if cfg.agent == "a2c":
        hyper.update(n_steps=8)
    cfg = cfg.model_copy(update={"hyperparams": hyper})
    path = train(cfg, tmp_path, progress=False)
    action = Policy(path).act(np.zeros((3, 9), np.float32))
    assert action.shape[0] == 3


def _weights(path: Path) -> list[np.ndarray]:
    from stable_baselines3 import PPO

    model = PPO.load(path, device="cpu")
    return [p.detach().numpy().copy() for p in model.policy.parameters()]


def test_sb3_training_resumes_from_the_last_checkpoint(tmp_path: Path) -> None:
    """A resume goes on from the newest checkpoint, deterministically: resumed twice from the
    same checkpoint, it trains the same network and records the same evaluations."""
    sets = [
        "n_envs=2",
        "overrides=[scenario.duration_s=100]",
        "hyperparams={n_steps: 16, batch_size: 16, n_epochs: 1}",
        "eval={episodes: 1, seed: 100000, every_steps: 32}",
    ]
    run = tmp_path / "run"
    train(load_train_config(TRAINING / "train_ppo.yaml", [*sets, "total_steps=64"]), run, False)
    first = sorted((run / "checkpoints").glob("*.zip"))
    assert first
    shutil.copytree(run, tmp_path / "again")
    from stable_baselines3 import PPO

    longer = load_train_config(TRAINING / "train_ppo.yaml", [*sets, "total_steps=128"])
    for folder in (run, tmp_path / "again"):
        train(longer, folder, False, resume=True)  # a changed total_steps needs --resume
    model = PPO.load(run / "model.zip", device="cpu")
    assert model.num_timesteps == 128  # 64 from the checkpoint, 64 more: not 128 from scratch + 64
    assert len(sorted((run / "checkpoints").glob("*.zip"))) > len(first)
    assert json.loads((run / "training.json").read_text())["resumed_from"] == [first[-1].name]
    again = _weights(tmp_path / "again" / "model.zip")
    assert all(
        np.array_equal(a, b) for a, b in zip(_weights(run / "model.zip"), again, strict=True)
    )
    with (
        np.load(run / "eval" / "evaluations.npz") as z,
        np.load(tmp_path / "again" / "eval" / "evaluations.npz") as z2,
    ):
        assert z["timesteps"].tolist() == [32, 64, 96, 128]  # kept up to the checkpoint, then on
        for key in ("timesteps", "results", "ep_lengths"):
            np.testing.assert_array_equal(z[key], z2[key])
    # SB3's callbacks wrote into staging folders; nothing is left of them
    assert not list(run.rglob(".staging"))
