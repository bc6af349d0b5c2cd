"""``qkf train``: bad input refused before any work (exit 2, one message, nothing written), a
rerun into the same --out (refused on a changed config; --resume, --force-new), total_steps
rounded to whole SB3 rollouts, and the tabular agent's TensorBoard log, checkpoints and
evaluations."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from agents.config import load_train_config
from agents.policy import Policy
from agents.tabular import TabularQAgent
from agents.training import plan_training, rounded_total_steps
from qkf.cli import app
from tests.conftest import CONFIGS, ROOT, TRAINING

runner = CliRunner()
TABULAR = str(TRAINING / "train_tabular.yaml")
PPO = str(TRAINING / "train_ppo.yaml")
TINY = ["--set", "n_envs=4", "--set", "overrides=[scenario.duration_s=100]"]
TAB = [*TINY, "--set", "eval={episodes: 2, seed: 100000, every_steps: 40}"]
PPO_TINY = [
    "--set", "n_envs=2",
    "--set", "overrides=[scenario.duration_s=100]",
    "--set", "hyperparams={n_steps: 16, batch_size: 16, n_epochs: 1}",
    "--set", "eval={episodes: 1, seed: 100000, every_steps: 40}",
]  # fmt: skip


def _train(config: str, out: Path, *extra: str) -> object:
    return runner.invoke(app, ["train", config, "--out", str(out), "--quiet", *extra])


def _ok(result: object) -> str:
    out: str = result.output  # type: ignore[attr-defined]
    assert result.exit_code == 0, out  # type: ignore[attr-defined]
    return out


def _refused(result: object, *needles: str) -> str:
    out: str = result.output  # type: ignore[attr-defined]
    assert result.exit_code == 2, out  # type: ignore[attr-defined]
    assert "Traceback" not in out and out.count("error:") == 1, out
    assert "pydantic" not in out, out
    for needle in needles:
        assert needle in out, out
    return out


def _info(out: Path) -> dict[str, Any]:
    return json.loads((out / "training.json").read_text())


# ------------------------------------------------------------------------------------------------
# bad input


@pytest.mark.parametrize(
    ("config", "sets", "needles"),
    [
        (TABULAR, ["scenario=/nonexistent.yaml"],
         ["scenario: /nonexistent.yaml: no such config file"]),
        (TABULAR, ["scenario=no_such_preset"],
         ["scenario: no_such_preset: no such config file or preset (presets: ", "thermal_snap"]),
        (PPO, ["hyperparams={learnin_rate: 0.1}"],
         ["hyperparams.learnin_rate: not a parameter of PPO (did you mean learning_rate?)"]),
        (PPO, ["hyperparams={seed: 1}"], ["hyperparams.seed: set by qkf train"]),
        (TABULAR, ["overrides=[scenario.duration_s=-5]"],
         ["overrides: ", "thermal_snap.yaml (with --set): scenario.duration_s: "]),
        (TABULAR, ["tabular={gama: 0.9}"],
         ["tabular.gama: not a parameter of the tabular agent (did you mean gamma?)"]),
        (TABULAR, ["tabular={alpha: 2}"], ["tabular.alpha: must be in (0, 1], got 2"]),
        (TABULAR, ["tabular={bins: {12: [0.0]}}"], ["tabular.bins: 12 is not an observation"]),
        (TABULAR, ["hyperparams={n_steps: 8}"], ["hyperparams: the tabular agent takes no"]),
        # SB3's constructor arguments, which the runner passes to the tabular agent too
        (TABULAR, ["tabular={device: cuda}"], ["tabular.device: set by qkf train (cpu)"]),
        (TABULAR, ["tabular={env: x}"], ["tabular.env: set by qkf train"]),
        (PPO, ["tabular={alpha: 0.5}"], ["tabular: only the tabular agent reads it"]),
        (PPO, ["hyperparams={n_steps: 0}"], ["hyperparams.n_steps: must be a positive integer"]),
        # a value only the algorithm itself can judge: refused when it is built, still before
        # anything is written
        (PPO, ["hyperparams={batch_size: 0}", "overrides=[scenario.duration_s=100]"],
         ["hyperparams: PPO refuses them: "]),
    ],
)  # fmt: skip
def test_bad_train_input_is_refused_before_anything_is_written(
    tmp_path: Path, config: str, sets: list[str], needles: list[str]
) -> None:
    out = tmp_path / "run"
    extra = [a for s in sets for a in ("--set", s)]
    text = _refused(_train(config, out, *extra), "invalid training config", *needles)
    assert f"{config} (with --set): " in text  # names the training config file
    assert not out.exists()


def test_a_directory_as_scenario(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _refused(_train(TABULAR, out, "--set", f"scenario={tmp_path}"), "scenario: ", "is a directory")
    assert not out.exists()


def test_message_names_the_file_and_the_field(tmp_path: Path) -> None:
    cfg = tmp_path / "train.yaml"
    cfg.write_text("agent: ppo\nhyperparams: {learnin_rate: 0.1}\n")
    out = tmp_path / "run"
    text = _refused(_train(str(cfg), out))
    assert (
        f"error: invalid training config\n  {cfg}: hyperparams.learnin_rate: not a parameter "
        "of PPO (did you mean learning_rate?)"
    ) in text
    assert not out.exists()


def test_flags_and_out_are_checked_first(tmp_path: Path) -> None:
    _refused(_train(TABULAR, tmp_path / "run", "--resume", "--force-new"), "exclude each other")
    assert not (tmp_path / "run").exists()
    taken = tmp_path / "taken"
    taken.write_text("mine")
    _refused(_train(TABULAR, taken, *TAB), "not a directory")
    assert taken.read_text() == "mine"
    _refused(_train(TABULAR, tmp_path / "run", "--resume", *TAB), "holds no previous run")
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------------------------------------
# reruns into the same --out


def test_changed_config_is_refused_with_the_fields_named(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=4"))
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    changed = ["--set", "episodes=4", "--set", "seed=1", "--set", "reward=likelihood"]
    text = _refused(
        _train(TABULAR, out, *TAB, *changed),
        "seed: 0 → 1",
        'reward: "oracle" → "likelihood"',
        "--resume",
        "--force-new",
    )
    assert "episodes" not in text.split("old → new:")[1].split("--resume")[0]  # not a difference
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before  # untouched
    # --resume may change how long to train, nothing else
    _refused(_train(TABULAR, out, *TAB, "--set", "episodes=8", "--set", "seed=1", "--resume"),
             "--resume", "seed: 0 → 1")  # fmt: skip
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_identical_rerun_of_a_complete_run_trains_nothing(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=4"))
    model = (out / "model.npz").read_bytes()
    text = _ok(_train(TABULAR, out, *TAB, "--set", "episodes=4"))
    assert "nothing to train" in text
    assert (out / "model.npz").read_bytes() == model


def test_force_new_discards_the_previous_run(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=8"))
    (out / "checkpoints" / "model_999_episodes.npz").write_bytes(b"stale")
    (out / "notes.txt").write_text("mine")  # not a run file: kept
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=4", "--set", "seed=1", "--force-new"))
    assert yaml.safe_load((out / "config.yaml").read_text())["seed"] == 1
    assert not (out / "checkpoints" / "model_999_episodes.npz").exists()
    assert not (out / "checkpoints" / "model_8_episodes.npz").exists()
    assert (out / "notes.txt").read_text() == "mine"
    info = _info(out)
    assert info["complete"] and info["resumed_from"] == [] and info["episodes"] == 4
    with np.load(out / "eval" / "evaluations.npz") as z:
        assert z["timesteps"].max() == info["num_timesteps"]  # only this run's evaluations


def test_resume_goes_on_with_more_episodes(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=4"))
    with np.load(out / "eval" / "evaluations.npz") as z:
        first = z["timesteps"].copy()
    text = _ok(_train(TABULAR, out, *TAB, "--set", "episodes=8", "--resume"))
    assert "resuming from" in text and "model_4_episodes.npz" in text
    assert "episodes: 4 → 8" in text
    agent = TabularQAgent.load(out / "model.npz")
    assert agent.episodes == 8 and agent.steps == 80  # 4 + 4 episodes of 10 steps
    info = _info(out)
    assert info["resumed_from"] == ["model_4_episodes.npz"] and info["complete"]
    assert yaml.safe_load((out / "config.yaml").read_text())["episodes"] == 8
    with np.load(out / "eval" / "evaluations.npz") as z:
        np.testing.assert_array_equal(z["timesteps"][: first.size], first)  # kept
        assert z["timesteps"][-1] == 80 and np.all(np.diff(z["timesteps"]) > 0)
    # asking for fewer episodes than the checkpoint has is refused
    _refused(_train(TABULAR, out, *TAB, "--set", "episodes=4", "--resume"), "episodes: ")


def test_an_interrupted_run_resumes_silently_with_the_same_config(tmp_path: Path) -> None:
    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=8"))
    # as if stopped after the first checkpoint
    (out / "model.npz").unlink()
    (out / "checkpoints" / "model_8_episodes.npz").unlink()
    info = _info(out)
    (out / "training.json").write_text(json.dumps({**info, "complete": False}))
    text = _ok(_train(TABULAR, out, *TAB, "--set", "episodes=8"))
    assert "resuming from" in text and "model_4_episodes.npz" in text
    assert TabularQAgent.load(out / "model.npz").episodes == 8
    assert _info(out)["complete"]


# ------------------------------------------------------------------------------------------------
# total_steps and SB3 reruns


def test_total_steps_is_rounded_to_whole_rollouts_reported_and_trained(tmp_path: Path) -> None:
    from stable_baselines3 import PPO as PPOClass

    out = tmp_path / "run"
    text = _ok(_train(PPO, out, *PPO_TINY, "--set", "total_steps=100"))
    assert "total_steps 100 → 128 (PPO rollouts of n_steps 16 × n_envs 2)" in text
    assert PPOClass.load(out / "model.zip", device="cpu").num_timesteps == 128
    assert yaml.safe_load((out / "config.yaml").read_text())["total_steps"] == 128
    info = _info(out)
    assert info["total_steps_requested"] == 100 and info["total_steps"] == 128
    assert info["num_timesteps"] == 128 and info["complete"]
    steps = sorted(int(p.stem.split("_")[1]) for p in (out / "checkpoints").glob("*.zip"))
    assert steps[-1] == 128 and all(s % 32 == 0 for s in steps)  # between rollouts
    with np.load(out / "eval" / "evaluations.npz") as z:
        assert z["results"].shape == (len(steps), 1)
    assert (out / "best" / "best_model.zip").is_file() and list((out / "tb").iterdir())
    # the same request again is the same run, complete
    assert "nothing to train" in _ok(_train(PPO, out, *PPO_TINY, "--set", "total_steps=100"))
    # --resume for more steps goes on from the final checkpoint
    text = _ok(_train(PPO, out, *PPO_TINY, "--set", "total_steps=150", "--resume"))
    assert "total_steps 150 → 160" in text and "model_128_steps.zip" in text
    assert PPOClass.load(out / "model.zip", device="cpu").num_timesteps == 160


def test_rounding_uses_the_algorithms_defaults() -> None:
    def rounded(name: str, *sets: str) -> tuple[int, str | None]:
        cfg = load_train_config(TRAINING / f"{name}.yaml", list(sets))
        total, rollout = rounded_total_steps(cfg)
        return total, rollout.describe() if rollout else None

    assert rounded("train_a2c", "n_envs=3", "total_steps=100") == (
        105, "A2C rollouts of n_steps 5 × n_envs 3"
    )  # fmt: skip
    assert rounded("train_ppo", "total_steps=8000", "hyperparams={n_steps: 512}") == (
        8192, "PPO rollouts of n_steps 512 × n_envs 16"
    )  # fmt: skip
    assert rounded("train_dqn", "total_steps=100000") == (
        100032, "DQN updates every train_freq 4 × n_envs 16"
    )  # fmt: skip
    assert rounded("train_tabular") == (50_000, None)


def test_planning_writes_nothing(tmp_path: Path) -> None:
    cfg = load_train_config(TRAINING / "train_ppo.yaml", ["total_steps=8000"])
    plan = plan_training(cfg, tmp_path / "run")
    assert plan.cfg.total_steps == 32768 and plan.checkpoint is None and not plan.discard
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------------------------------------
# what a tabular run leaves


def test_tabular_writes_tb_checkpoints_evaluations_and_best(tmp_path: Path) -> None:
    from tensorboard.backend.event_processing.event_file_loader import EventFileLoader

    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=8"))
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        "model_4_episodes.npz",
        "model_8_episodes.npz",
    ]
    with np.load(out / "eval" / "evaluations.npz") as z:
        np.testing.assert_array_equal(z["timesteps"], [40, 80])  # episode ends at 40 steps each
        assert z["results"].shape == (2, 2) and np.all(np.isfinite(z["results"]))
        np.testing.assert_array_equal(z["ep_lengths"], np.full((2, 2), 10))
    best = json.loads((out / "best" / "best.json").read_text())
    assert TabularQAgent.load(out / "best" / "best_model.npz").steps == best["timestep"]
    tags = {
        v.tag
        for f in (out / "tb" / "tabular_1").iterdir()  # SB3's naming: <tb_log_name>_<run>
        for ev in EventFileLoader(str(f)).Load()
        for v in ev.summary.value
    }
    assert {
        "rollout/ep_return",
        "train/epsilon",
        "train/states_visited",
        "eval/mean_reward",
    } <= tags
    info = _info(out)
    assert info["complete"] and info["episodes"] == 8 and info["num_timesteps"] == 80
    assert not [p for p in out.rglob(".*")]  # no temporary files left


def test_tabular_training_is_deterministic_by_seed(tmp_path: Path) -> None:
    for name in ("a", "b"):
        _ok(_train(TABULAR, tmp_path / name, *TAB, "--set", "episodes=8"))
    a, b = (TabularQAgent.load(tmp_path / n / "model.npz") for n in ("a", "b"))
    np.testing.assert_array_equal(a.table, b.table)
    np.testing.assert_array_equal(a.visits, b.visits)
    with (
        np.load(tmp_path / "a/eval/evaluations.npz") as za,
        np.load(tmp_path / "b/eval/evaluations.npz") as zb,
    ):
        np.testing.assert_array_equal(za["results"], zb["results"])


def test_a_policy_loads_without_its_training_scenario(tmp_path: Path) -> None:
    scenario = tmp_path / "my_scenario.yaml"
    scenario.write_text((CONFIGS / "thermal_snap.yaml").read_text())
    out = tmp_path / "run"
    _ok(_train(TABULAR, out, *TAB, "--set", "episodes=4", "--set", f"scenario={scenario}"))
    scenario.unlink()  # the policy acts on any scenario
    assert Policy(out / "model.npz").act(np.zeros((2, 9), np.float32)).shape == (2,)


def test_reading_a_tabular_config_does_not_load_torch() -> None:
    code = (
        "import sys\nfrom agents.config import load_train_config\n"
        "load_train_config('train_tabular')\nprint('torch' in sys.modules)"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == "False"
