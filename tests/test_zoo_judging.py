"""A zoo entry of a problem other than transfer alignment is judged by ``qkf judge`` (its
``judging:`` section): every training seed's policy against every baseline on the same trials
of each family, written into ``evaluation/`` and the card; its numbers recomputed here from the
run's own ``trials.csv``. The transfer-alignment sections are refused for such an entry."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents.zoo import load_entry
from agents.zoo.commands import evaluate_entry
from qkf.core.config import ConfigError

TRAIN = """agent: ppo
env: qkf/RedundantGyroCalibration-v3
scenario: gyro_noise_levels
action_type: discrete
reward: mean_square
period_s: 10
n_envs: 2
total_steps: 64
hyperparams: {n_steps: 8, batch_size: 16}
"""


def _model(path: Path, seed: int) -> None:
    """An untrained PPO of the v3 gyro environment with large weights (its greedy κ follows
    the observation), saved as a training run would save it."""
    import torch
    from stable_baselines3 import PPO

    from envs.redundant_gyros.sb3 import BatchedGyroSB3Env

    env = BatchedGyroSB3Env(2, "gyro_noise_levels", observation="v3")
    model = PPO("MlpPolicy", env, n_steps=8, batch_size=16, seed=seed, device="cpu")
    first: Any = model.policy.mlp_extractor.policy_net[0]
    with torch.no_grad():
        first.weight.mul_(30.0)
        model.policy.action_net.weight.mul_(30.0)
    model.save(path)


def _entry(tmp_path: Path, judging: str) -> Path:
    folder = tmp_path / "zoo" / "gyro_tiny"
    folder.mkdir(parents=True)
    (folder / "train.yaml").write_text(TRAIN)
    (folder / "zoo.yaml").write_text(f"train: train.yaml\nseeds: [0, 1]\n{judging}")
    for seed in (0, 1):
        (folder / f"seed_{seed}").mkdir()
        shutil.copy(folder / "train.yaml", folder / f"seed_{seed}" / "config.yaml")
        _model(folder / f"seed_{seed}" / "model.zip", seed)
    return folder


def test_a_gyro_entry_is_judged_by_qkf_judge_and_its_card_says_so(tmp_path: Path) -> None:
    folder = _entry(
        tmp_path,
        "judging:\n  families: [gyro_control, gyro_noise_levels]\n"
        "  baselines: [constant, level-informed]\n  trials: 16\n"
        "  overrides: [scenario.duration_s=160]\n",
    )
    entry = load_entry(folder)
    assert entry.problem.name == "redundant_gyros"
    said: list[str] = []
    card = evaluate_entry(entry, tmp_path / "work", progress=False, say=said.append)
    assert any("judging on the redundant_gyros families" in s for s in said)
    evaluation = tmp_path / "work" / "evaluation"
    with (evaluation / "judging_seed5000000_trials.csv").open() as f:
        trials = list(csv.DictReader(f))
    with (evaluation / "zoo_judging.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["scenario"] for r in rows} == {"gyro_control", "gyro_noise_levels"}
    for family in ("gyro_control", "gyro_noise_levels"):
        mine = [t for t in trials if t["family"] == family]
        assert len(mine) == 16
        ratios = []
        for seed in (0, 1):
            a = np.array([float(t[f"gyro_tiny#{seed}"]) for t in mine])
            b = np.array([float(t["constant"]) for t in mine])
            want = np.sqrt(np.sum(a**2) / np.sum(b**2))
            got = [r for r in rows if r["scenario"] == family and r["policy"] == f"gyro_tiny#{seed}"
                   and r["quantity"] == "ratio" and r["versus"] == "constant"]  # fmt: skip
            assert len(got) == 1 and float(got[0]["value"]) == pytest.approx(want, rel=1e-5)
            assert float(got[0]["lo"]) <= want <= float(got[0]["hi"])
            ratios.append(want)
        iqm = [r for r in rows if r["scenario"] == family and r["policy"] == "gyro_tiny:IQM"
               and r["versus"] == "constant"]  # fmt: skip
        assert float(iqm[0]["lo"]) == pytest.approx(min(ratios), rel=1e-5)
        assert float(iqm[0]["hi"]) == pytest.approx(max(ratios), rel=1e-5)
    text = card.read_text()
    assert "## Judged on the problem's families" in text and "qkf judge redundant_gyros" in text
    assert "### gyro_control (16 trials)" in text and "| gyro_tiny#1 |" in text


def test_a_gyro_entry_refuses_the_transfer_alignment_sections_and_bad_judging(
    tmp_path: Path,
) -> None:
    folder = _entry(tmp_path, "families: {}\n")
    with pytest.raises(ConfigError, match="judged with judging:"):
        load_entry(folder)
    (folder / "zoo.yaml").write_text(
        "train: train.yaml\nseeds: [0, 1]\njudging:\n  baselines: [constant, kf-tuned]\n"
    )
    entry = load_entry(folder)
    with pytest.raises(ConfigError, match=r"zoo.yaml: judging: --methods: .*'kf-tuned'"):
        evaluate_entry(entry, tmp_path / "work", progress=False, say=lambda s: None)
    assert not (tmp_path / "work" / "evaluation").exists()


def test_promote_keeps_one_best_per_problem(tmp_path: Path) -> None:
    """Promoting a gyro entry writes best_redundant_gyros/ and leaves best/ (the
    transfer-alignment policy the README runs) as it was, and the reverse."""
    from agents.zoo import ZOO_DIR, list_entries
    from agents.zoo.commands import promote
    from agents.zoo.entry import best_folder

    for name in ("ppo_gyro_mixture", "ppo_snap_random"):
        (tmp_path / name).mkdir()
        for file in ("zoo.yaml", "model.zip", "config.yaml", "card.md"):
            shutil.copy(ZOO_DIR / name / file, tmp_path / name / file)
    ta = promote(load_entry("ppo_snap_random", tmp_path), tmp_path)
    assert ta == tmp_path / "best" == best_folder("transfer_alignment", tmp_path)
    before = {p.name: p.read_bytes() for p in ta.iterdir()}
    gyro = promote(load_entry("ppo_gyro_mixture", tmp_path), tmp_path)
    assert gyro == tmp_path / "best_redundant_gyros"
    assert {p.name: p.read_bytes() for p in ta.iterdir()} == before
    assert (gyro / "SOURCE").read_text() == "ppo_gyro_mixture\n"
    model = (tmp_path / "ppo_gyro_mixture" / "model.zip").read_bytes()
    assert (gyro / "model.zip").read_bytes() == model
    promote(load_entry("ppo_snap_random", tmp_path), tmp_path)  # again: gyro's best stays
    assert (gyro / "model.zip").read_bytes() == model
    assert [e.name for e in list_entries(tmp_path)] == ["ppo_gyro_mixture", "ppo_snap_random"]
