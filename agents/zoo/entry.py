"""A zoo entry: its ``zoo.yaml`` schema, where its files are, and which training seed it ships.

::

    description: PPO on thermal_snap_random, v1 observation, misalignment_gain reward
    train: train_ppo_snap_random # the training config: a preset name or a path relative to
                                 # the entry folder (a seed's config.yaml is the exact one)
    seeds: [0, 1, 2]             # training seeds (≥ 3 for intervals across seeds)
    judge:                       # the held-out comparison (benchmark seeds, not env seeds)
      scenario: thermal_snap_random
      seed: 7000
      trials: 64
      metric: ma_urad_settled
      baselines: [kf, kf-tuned, sage-husa, qkf, vbakf, imm, covariance-matching, mmae]
    also:                        # further scenarios, reported the same way
      - {scenario: thermal_drift_random, seed: 7000, trials: 32, baselines: [kf, kf-tuned]}
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from agents.config import TrainConfig, load_train_config
from qkf.core.config import ConfigError, StrictModel, load_model

ZOO_DIR = Path(__file__).resolve().parent
"""The shipped zoo: ``agents/zoo/`` (one folder per entry, ``best/`` the promoted one)."""

SPEC_FILE = "zoo.yaml"


class JudgeCase(StrictModel):
    """One benchmark the entry's policies are judged on (all training seeds, paired)."""

    scenario: str
    overrides: list[str] = Field(default_factory=list)  # --set style, of the scenario
    seed: Annotated[int, Field(ge=0)] = 7000
    trials: Annotated[int, Field(ge=2)] = 64
    metric: str = "state_settled"
    baselines: list[str] = Field(default_factory=lambda: ["kf", "kf-tuned"])
    oracle: bool = True  # also run the truth-tuned oracle schedule (the upper reference)


class ZooSpec(StrictModel):
    description: str = ""
    train: str
    seeds: Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)] = Field(
        default_factory=lambda: [0, 1, 2]
    )
    judge: JudgeCase
    also: list[JudgeCase] = Field(default_factory=list)

    def cases(self) -> list[JudgeCase]:
        """The main judging case first, then the others."""
        return [self.judge, *self.also]


@dataclass(frozen=True)
class ZooEntry:
    """An entry folder with its spec and training config."""

    name: str
    folder: Path
    spec: ZooSpec
    train_cfg: TrainConfig

    @property
    def train_source(self) -> str:
        """The training config as ``qkf train`` takes it: a path or a preset name."""
        local = self.folder / self.spec.train
        return str(local) if local.is_file() else self.spec.train

    def seed_dir(self, seed: int) -> Path:
        return self.folder / f"seed_{seed}"

    def model_name(self) -> str:
        return "model.npz" if self.train_cfg.agent == "tabular" else "model.zip"

    def seed_model(self, seed: int) -> Path:
        return self.seed_dir(seed) / self.model_name()

    def trained_seeds(self) -> list[int]:
        """The training seeds whose model is in the entry."""
        return [s for s in self.spec.seeds if self.seed_model(s).is_file()]

    def validation_score(self, seed: int) -> float:
        """Mean return of the last periodic evaluation on the held-out environment seed
        (``eval.seed`` of the training config; never a judging seed); −inf without one."""
        path = self.seed_dir(seed) / "evaluations.npz"
        if not path.is_file():
            return float("-inf")
        with np.load(path) as data:
            results = np.asarray(data["results"], dtype=float)
        return float(results[-1].mean()) if results.size else float("-inf")

    def selected_seed(self) -> int | None:
        """The shipped training seed: the best validation score (ties: the first seed)."""
        seeds = self.trained_seeds()
        return max(seeds, key=self.validation_score) if seeds else None

    def wall_times(self) -> dict[int, float]:
        """Training wall time per seed, s (``zoo_train.json`` of each seed folder)."""
        times = {}
        for s in self.trained_seeds():
            path = self.seed_dir(s) / "zoo_train.json"
            if path.is_file():
                times[s] = float(json.loads(path.read_text())["wall_s"])
        return times


def load_entry(name: str | Path, zoo: Path = ZOO_DIR) -> ZooEntry:
    """The entry ``zoo/<name>`` (or a folder path); ``ConfigError`` names the file and field."""
    folder = Path(name) if Path(name).is_dir() and Path(name, SPEC_FILE).is_file() else zoo / name
    spec_file = folder / SPEC_FILE
    if not spec_file.is_file():
        known = ", ".join(e.name for e in list_entries(zoo)) or "none"
        raise ConfigError(f"{spec_file}: no such zoo entry (entries: {known})")
    spec = load_model(ZooSpec, spec_file, None, "zoo entry")
    local = folder / spec.train
    try:
        train_cfg = load_train_config(local if local.is_file() else spec.train)
    except ConfigError as exc:
        raise ConfigError(f"{spec_file}: train: {spec.train}: {exc}") from None
    return ZooEntry(folder.name, folder, spec, train_cfg)


def list_entries(zoo: Path = ZOO_DIR) -> list[ZooEntry]:
    """Every entry of the zoo with a readable spec, by name (``best/`` is a copy, not listed)."""
    entries = []
    for folder in sorted(p for p in zoo.iterdir() if (p / SPEC_FILE).is_file()):
        if folder.name != "best":
            entries.append(load_entry(folder.name, zoo))
    return entries
