"""The environments with their real clients, unmodified: rendering as Gymnasium and SB3 ask for
it, Stable-Baselines3's ``make_vec_env`` and ``SubprocVecEnv`` training PPO, RL Zoo3's
``train`` with the shipped hyperparameter file, and the README's RL example without warnings."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env

import envs
from envs import ENV_ID_V2, ENV_ID_V3, ENV_ID_V4, ENVIRONMENTS, GYRO_ENV_ID
from envs.common.render import FRAME_HEIGHT_PX, FRAME_WIDTH_PX, RENDER_FPS

ROOT = Path(__file__).resolve().parents[1]
ZOO_HYPERPARAMS = ROOT / "agents" / "rl_zoo3" / "ppo.yml"
SHORT = ["scenario.duration_s=200"]  # 20 decision periods of 10 s per episode
GYRO_SHORT = ["scenario.duration_s=90"]  # fault at 60 s: 3 calibrated periods of 10 s
ALL_IDS = ENVIRONMENTS.names()  # every registered environment
# tiny PPO: two 32-step rollouts of 2 envs cover learn(300) in 5 updates
PPO_SMALL = {"n_steps": 32, "batch_size": 32, "n_epochs": 1, "device": "cpu", "seed": 0}
LEARN_STEPS = 300


def _short(env_id: str) -> list[str]:
    return GYRO_SHORT if env_id == GYRO_ENV_ID else SHORT


def _make(env_id: str, **kwargs: Any) -> gym.Env:  # type: ignore[type-arg]
    with warnings.catch_warnings():  # v0/v1: Gymnasium's "out of date" hint, by design
        warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)
        return gym.make(env_id, overrides=_short(env_id), **kwargs)


def _is_frame(frame: Any) -> bool:
    return (
        isinstance(frame, np.ndarray)
        and frame.shape == (FRAME_HEIGHT_PX, FRAME_WIDTH_PX, 3)
        and frame.dtype == np.uint8
    )


# ----------------------------------------------------------------------------------------------
# rendering


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_rgb_array_frames_show_the_episode(env_id: str) -> None:
    env = _make(env_id, render_mode="rgb_array")
    assert env.metadata["render_modes"] == ["rgb_array"]
    assert env.metadata["render_fps"] == RENDER_FPS
    env.reset(seed=3)
    first = env.render()
    assert _is_frame(first)
    for a in (0, 10, 5):
        env.step(a)
    later = env.render()
    assert _is_frame(later)
    assert not np.array_equal(first, later)  # the steps were drawn
    env.reset(seed=3)
    np.testing.assert_array_equal(env.render(), first)  # reset starts the drawing anew


@pytest.mark.parametrize("env_id", [ENV_ID_V2, GYRO_ENV_ID])
def test_rendering_leaves_the_episode_unchanged(env_id: str) -> None:
    plain, drawn = _make(env_id), _make(env_id, render_mode="rgb_array")
    a, b = plain.reset(seed=5)[0], drawn.reset(seed=5)[0]
    np.testing.assert_array_equal(a, b)
    for action in (1, 9, 4):
        x, y = plain.step(action), drawn.step(action)
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1:4] == y[1:4]
    assert plain.unwrapped.render() is None  # no render mode: nothing drawn
    assert _is_frame(drawn.render())


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_unsupported_render_modes_fail_at_construction(env_id: str) -> None:
    cls = gym.spec(env_id).entry_point
    assert isinstance(cls, str)
    env_class = gym.envs.registration.load_env_creator(cls)
    for mode in ("human", "ansi", "rgb_array_list", "depth_array"):
        with pytest.raises(ValueError, match=r"not supported; use one of None, 'rgb_array'"):
            env_class(overrides=_short(env_id), render_mode=mode)
    # gym.make serves "human" and "*_list" itself from "rgb_array" (its HumanRendering and
    # RenderCollection wrappers); a mode it cannot derive reaches the environment and fails
    with (
        warnings.catch_warnings(),
        pytest.raises(ValueError, match="'ansi' is not supported"),
    ):
        warnings.filterwarnings("ignore", ".*not in the possible render_modes", UserWarning)
        _make(env_id, render_mode="ansi")


@pytest.mark.parametrize("env_id", [ENV_ID_V2, GYRO_ENV_ID])
def test_checker_passes_in_rgb_array_mode_without_warnings(env_id: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(_make(env_id, render_mode="rgb_array").unwrapped)


def test_vector_env_renders_one_frame_per_sub_env() -> None:
    vec = gym.make_vec(
        ENV_ID_V2,
        num_envs=2,
        vectorization_mode="vector_entry_point",
        render_mode="rgb_array",
        overrides=SHORT,
    )
    assert isinstance(vec.unwrapped, envs.BatchedTransferAlignmentEnv)
    assert vec.metadata["render_modes"] == ["rgb_array"]
    vec.reset(seed=0)
    empty = vec.render()
    assert isinstance(empty, tuple) and len(empty) == 2 and all(_is_frame(f) for f in empty)
    steps = vec.unwrapped.episode_steps  # type: ignore[attr-defined]
    for _ in range(steps):  # the last of these ends both episodes
        vec.step(np.array([2, 8]))
    full = vec.render()
    assert full is not None and not np.array_equal(full[0], empty[0])
    vec.step(np.array([2, 8]))  # next-step autoreset: new episodes, new drawings
    np.testing.assert_array_equal(vec.render()[0], empty[0])  # type: ignore[index]
    with pytest.raises(ValueError, match="not supported"):
        gym.make_vec(ENV_ID_V2, num_envs=2, render_mode="human", overrides=SHORT)
    assert gym.make_vec(ENV_ID_V2, num_envs=2, overrides=SHORT).render() is None


# ----------------------------------------------------------------------------------------------
# Stable-Baselines3 and RL Zoo3


@pytest.mark.slow  # trains PPO
def test_make_vec_env_trains_ppo() -> None:
    """SB3's ``make_vec_env`` asks for ``render_mode="rgb_array"``; it used to fail there."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    vec = make_vec_env(ENV_ID_V2, n_envs=2, seed=0, env_kwargs={"overrides": SHORT})
    assert vec.render_mode == "rgb_array"
    model = PPO("MlpPolicy", vec, **PPO_SMALL).learn(LEARN_STEPS)
    assert model.num_timesteps >= LEARN_STEPS
    frames = vec.get_images()
    assert len(frames) == 2 and all(_is_frame(f) for f in frames)
    vec.close()


@pytest.mark.slow  # trains PPO in spawned worker processes
@pytest.mark.parametrize("start_method", ["spawn"])
def test_subproc_vec_env_trains_ppo(start_method: str) -> None:
    """Two worker processes. Not ``fork``: once the parent has run a parallel numba kernel,
    OpenMP kills forked children ("fork() called from a process already using GNU OpenMP").
    A spawned worker starts a fresh interpreter: the ``envs:`` prefix makes Gymnasium import
    ``envs`` there (and so register the ids) before looking the id up."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = make_vec_env(
        f"envs:{ENV_ID_V2}",
        n_envs=2,
        seed=0,
        env_kwargs={"overrides": SHORT},
        vec_env_cls=SubprocVecEnv,
        vec_env_kwargs={"start_method": start_method},
    )
    try:
        assert len({p.pid for p in vec.processes}) == 2  # type: ignore[attr-defined]
        assert vec.get_attr("episode_steps") == [20, 20]  # the short scenario, in each worker
        model = PPO("MlpPolicy", vec, **PPO_SMALL).learn(LEARN_STEPS)
        assert model.num_timesteps >= LEARN_STEPS
    finally:
        vec.close()


def test_zoo_hyperparameters_mirror_the_training_presets() -> None:
    """Every registered environment has an entry, and the v2 and v3 entries are the presets
    they name."""
    zoo = yaml.safe_load(ZOO_HYPERPARAMS.read_text())
    assert set(zoo) == set(ALL_IDS)
    for env_id, name in [
        (ENV_ID_V2, "train_ppo_snap_random_v2"),
        (ENV_ID_V3, "train_ppo_mixed_v3"),
        (ENV_ID_V4, "train_ppo_residual_glr_v4"),
    ]:
        preset = yaml.safe_load((ROOT / "configs" / "training" / f"{name}.yaml").read_text())
        entry = zoo[env_id]
        assert {k: entry[k] for k in preset["hyperparams"]} == preset["hyperparams"]
        assert entry["n_envs"] == preset["n_envs"] and entry["n_timesteps"] == preset["total_steps"]
        assert entry.get("frame_stack", 1) == preset.get("frame_stack", 1)
        for key in ("scenario", "action_type", "reward", "period_s"):
            assert entry["env_kwargs"][key] == preset[key]
        wrapper = {"scale": preset["reward_scale"]}
        if preset.get("reward_clip") is not None:
            wrapper["clip"] = preset["reward_clip"]
        assert entry["vec_env_wrapper"] == [{"agents.common.vec_env.ScaledReward": wrapper}]
        for key, value in preset.get("env_kwargs", {}).items():
            if key != "expert":  # RL Zoo3 does not clone: no expert to ask
                assert entry["env_kwargs"][key] == value


@pytest.mark.slow  # trains PPO through RL Zoo3
def test_rl_zoo3_trains_ppo(tmp_path: Path) -> None:
    """``python -m rl_zoo3.train`` as a user runs it, offline, in a folder of its own."""
    cmd = [
        sys.executable,
        "-m",
        "rl_zoo3.train",
        "--gym-packages",
        "envs",
        "--env",
        ENV_ID_V2,
        "--algo",
        "ppo",
        "-n",
        str(LEARN_STEPS),
        "--seed",
        "0",
        "--num-threads",
        "1",
        "--conf-file",
        str(ZOO_HYPERPARAMS),
        "-f",
        "logs",
        # --env-kwargs replaces the entry's env_kwargs: the preset's, on a short scenario
        "--env-kwargs",
        'scenario:"thermal_snap_random"',
        'reward:"misalignment_gain"',
        f"overrides:{SHORT!r}",
        "--hyperparams",
        "n_envs:2",
        "n_steps:32",
        "batch_size:32",
        "n_epochs:1",
    ]
    # the checked-out code first, wherever the project is installed from
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path}
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    elapsed = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr[-3000:]
    run = tmp_path / "logs" / "ppo" / "qkf-TransferAlignment-v2_1"
    assert (run / "qkf-TransferAlignment-v2.zip").is_file()
    saved = yaml.unsafe_load((run / "qkf-TransferAlignment-v2" / "config.yml").read_text())
    assert dict(saved)["env_kwargs"]["overrides"] == SHORT
    monitor = (run / "0.monitor.csv").read_text().splitlines()
    assert len(monitor) > 2  # episodes of 20 steps were completed and logged
    print(f"rl_zoo3.train {LEARN_STEPS} steps: {elapsed:.1f} s")


def test_readme_rl_example_runs_without_warnings() -> None:
    """The README shows the current version: no "out of date" warning (or any other)."""
    text = (ROOT / "README.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if "gym." in b]
    assert ENV_ID_V4 in block
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec(compile(block.replace("num_envs=64", "num_envs=2"), "README.md", "exec"), {})
