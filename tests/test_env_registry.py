"""The environment registry (``envs.ENVIRONMENTS``): every entry agrees with Gymnasium's
registration and with the environment it names, and ``agents/`` knows no environment by name
(docs/environment.md, "The environment registry")."""

from __future__ import annotations

import ast
import re
import warnings
from pathlib import Path

import gymnasium as gym
import pytest
from gymnasium.envs.registration import registry as gym_registry

import envs
from envs import ENVIRONMENTS
from qkf.core.registry import load_object

ROOT = Path(__file__).resolve().parents[1]
SHORT = {
    "transfer_alignment": ["scenario.duration_s=100"],
    "redundant_gyros": ["scenario.duration_s=90"],
}


def test_every_qkf_id_is_registered_in_both_registries() -> None:
    qkf_ids = {i for i in gym_registry if i.startswith("qkf/")}
    assert qkf_ids == set(ENVIRONMENTS.names())
    assert ENVIRONMENTS.names()[:3] == [envs.ENV_ID, envs.ENV_ID_V1, envs.ENV_ID_V2]


@pytest.mark.parametrize("env_id", ENVIRONMENTS.names())
def test_an_entry_describes_its_environment(env_id: str) -> None:
    spec = ENVIRONMENTS[env_id]
    gym_spec = gym_registry[env_id]
    assert spec.id == env_id
    assert gym_spec.entry_point == spec.entry_point
    assert gym_spec.vector_entry_point == spec.vector_entry_point
    assert gym_spec.kwargs == spec.kwargs and gym_spec.max_episode_steps is None
    with warnings.catch_warnings():  # v0/v1: Gymnasium's "out of date" hint, by design
        warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)
        env = gym.make(env_id, overrides=SHORT[spec.problem])
    assert isinstance(env.unwrapped, load_object(spec.entry_point))
    assert env.observation_space.shape == (spec.observation_size,)
    for reward in spec.rewards:  # every reward of the entry is one the environment takes
        gym.make(env_id, overrides=SHORT[spec.problem], reward=reward).reset(seed=0)
    if spec.sb3_vec_env is not None:
        from stable_baselines3.common.vec_env import VecEnv

        vec = load_object(spec.sb3_vec_env)(2, overrides=SHORT[spec.problem], **spec.kwargs)
        assert isinstance(vec, VecEnv)
        assert vec.observation_space.shape == (spec.observation_size,)


@pytest.mark.parametrize("env_id", [envs.ENV_ID_V2, envs.GYRO_ENV_ID])
def test_scenario_check_blames_the_scenario_or_the_overrides(env_id: str) -> None:
    check = ENVIRONMENTS[env_id].check_scenario
    good = "thermal_snap" if env_id == envs.ENV_ID_V2 else "five_gyros_s_bias"
    assert check(good, []) == []
    (line,) = check("no_such_preset", [])
    assert line.startswith("scenario: no_such_preset: no such config file or preset")
    lines = check(good, ["scenario.dt_s=-1"])
    assert lines and all(line.startswith("overrides: ") for line in lines)
    assert check(good, ["no_such.key=1"])[0].startswith("overrides: ")


def test_a_gyro_scenario_must_name_a_gyro_to_calibrate() -> None:
    (line,) = ENVIRONMENTS[envs.GYRO_ENV_ID].check_scenario("five_gyros", [])
    assert line.startswith("scenario: no gyro to calibrate")


def _code_words(path: Path) -> set[str]:
    """The names and string constants of a module's code (docstrings left out: an example in
    prose is not a branch)."""
    tree = ast.parse(path.read_text())
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    words: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            if id(node) not in docstrings:
                words.add(node.value)
        elif isinstance(node, ast.Name):
            words.add(node.id)
        elif isinstance(node, ast.Attribute):
            words.add(node.attr)
        elif isinstance(node, ast.alias):
            words.update({node.name, node.asname or ""})
    return words


def test_agents_know_no_environment_by_name() -> None:
    """Everything environment-specific comes from the registry: no environment id, and no
    per-environment name (``TA_…``, ``GYRO_…``, a class of one environment), appears in the code
    of ``agents/``."""
    ids = [re.escape(i) for i in ENVIRONMENTS.names()]
    pattern = re.compile("|".join([*ids, r"\bTA_", r"\bGYRO_", r"TransferAlignment", r"Gyro"]))
    offenders = {
        str(p.relative_to(ROOT)): sorted(w for w in _code_words(p) if pattern.search(w))
        for p in sorted((ROOT / "agents").rglob("*.py"))
    }
    assert {k: v for k, v in offenders.items() if v} == {}
