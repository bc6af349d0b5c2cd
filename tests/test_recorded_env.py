"""The replay environment: ``gym.make("qkf/TransferAlignment-…", data=FILE)`` steps through a
recorded run (docs/recorded_data.md, "Replay environment")."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from envs.transfer_alignment import BatchedEpisodes
from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.recorded.writer import write_recorded
from qkf.transfer_alignment.scenario import simulate

ROOT = Path(__file__).resolve().parents[1]
SETS = ["scenario.duration_s=300"]
ENV = "qkf/TransferAlignment-v3"


def test_replay_equals_the_simulated_episode(tmp_path: Path) -> None:
    cfg = load_config("paper", SETS)
    data = simulate(cfg, 12, [0])
    write_recorded(tmp_path / "r.csv", data)
    env = gym.make(ENV, scenario="paper", overrides=SETS, data=str(tmp_path / "r.csv"),
                   reward="relative_state_gain")  # fmt: skip
    obs, info = env.reset(seed=1)
    assert info["reward_available"] and info["file"].endswith("r.csv")
    core = BatchedEpisodes(cfg, 1, "relative_state_gain", observation="v3")
    obs_sim = core.load(data)[0]
    np.testing.assert_allclose(obs, obs_sim, rtol=1e-9)
    actions = [0, 5, 10, 3, 7] * 10
    kappas = np.asarray(cfg.adaptive.actions.values())
    n_act = kappas.size
    for step, a in enumerate(actions[: env.unwrapped.episode_steps]):
        obs, reward, term, trunc, info = env.step(a)
        out = core.step(np.array([kappas[a]]), np.array([a / (n_act - 1)]))
        np.testing.assert_allclose(obs, out.obs[0], rtol=1e-9, atol=1e-12)
        assert reward == pytest.approx(float(out.reward[0]), rel=1e-9, abs=1e-15)
        np.testing.assert_allclose(info["errors"], out.errors[0], rtol=1e-9, atol=1e-12)
        if term or trunc:
            assert step == env.unwrapped.episode_steps - 1
            break


def test_without_truth_the_reward_is_zero(tmp_path: Path) -> None:
    cfg = load_config("paper", SETS)
    write_recorded(tmp_path / "t.csv", simulate(cfg, 3, [0]), truth=False)
    env = gym.make(ENV, overrides=SETS, data=tmp_path / "t.csv", reward="relative_state_gain")
    _, info = env.reset(seed=0)
    assert info["reward_available"] is False
    steps, rewards = 0, []
    while True:
        obs, reward, term, trunc, info = env.step(env.action_space.sample())
        steps += 1
        rewards.append(reward)
        assert np.isfinite(obs).all() and np.isnan(info["errors"]).all()
        assert info["reward_available"] is False
        if term or trunc:
            break
    assert trunc and not term and steps == env.unwrapped.episode_steps
    assert rewards == [0.0] * steps


def test_several_files_are_picked_by_the_seed(tmp_path: Path) -> None:
    cfg = load_config("paper", SETS)
    for i in range(4):
        write_recorded(tmp_path / f"f{i}.csv", simulate(cfg, 30, [i]), truth=False)
    env = gym.make(ENV, overrides=SETS, data=tmp_path)
    picked = [env.reset(seed=s)[1]["file"] for s in range(12)]
    assert len(set(picked)) > 1
    assert picked == [env.reset(seed=s)[1]["file"] for s in range(12)]


def test_a_bad_file_is_refused_by_name(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,gyro_wx_rad_s\n0,1\n")
    with pytest.raises(ConfigError, match=r"bad\.csv: missing column"):
        gym.make(ENV, overrides=SETS, data=bad)


@pytest.mark.slow
def test_the_shipped_policy_steps_through_a_recording(tmp_path: Path) -> None:
    from agents.policy import Policy

    policy = Policy(ROOT / "agents" / "zoo" / "best" / "model.zip")
    cfg = load_config("paper", SETS)
    write_recorded(tmp_path / "p.csv", simulate(cfg, 8, [0]), truth=False)
    env = gym.make(policy.cfg.env, overrides=SETS, data=tmp_path / "p.csv")
    obs, _ = env.reset(seed=0)
    policy.reset(1)
    kappas = []
    while True:
        obs, _, term, trunc, info = env.step(policy.act(obs[None])[0])
        kappas.append(info["kappa"])
        if term or trunc:
            break
    assert trunc and len(kappas) == env.unwrapped.episode_steps


def test_the_batched_vector_env_refuses_recorded_data(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not replay recorded data"):
        gym.make_vec(ENV, num_envs=2, data=tmp_path / "x.csv")
