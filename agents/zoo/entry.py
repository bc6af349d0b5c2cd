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
    families:                    # the scenario families (qkf study families), state_settled
      families: [steady_random, thermal_snap_random]  # default: every family
      trials: 100                # per family (default 100)
      seed: 9000                 # a judging seed, [0, 1 000 000) (default 9000)
      baselines: [kf, kf-tuned, clock, hindsight]   # default: the families study's methods

``judge:`` runs the problem's bench (:class:`qkf.core.studies.Bench`) and ``families:`` its
families study (:class:`qkf.core.studies.FamiliesStudy`): transfer alignment has both. An entry
of any problem (its training environment's, ``qkf.core.problem.problem_of_env``) can be judged
by ``qkf judge``::

    judging:                     # qkf judge PROBLEM on the problem's families
      families: [gyro_noise_levels, gyro_control]   # default: every family of the problem
      baselines: [constant, clock, nis-adaptive]    # the problem's method specs; every
                                                    # policy is compared with each
      trials: 64                 # per family (default 64)
      seed: 5000000              # default: the problem's first judging seed

An entry needs ``judge:``, ``families:`` or ``judging:``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, field_validator, model_validator

from agents.algorithms import ALGORITHMS
from agents.config import TrainConfig, load_train_config
from qkf.core.config import ConfigError, StrictModel, load_model
from qkf.core.method_specs import spec_label
from qkf.core.problem import PROBLEMS, Problem, problem_of_env
from qkf.core.seed_groups import SEED_MARK

ZOO_DIR = Path(__file__).resolve().parent
"""The shipped zoo: ``agents/zoo/`` (one folder per entry; ``best/``, ``best_<problem>/``: the
promoted ones)."""

SPEC_FILE = "zoo.yaml"

BEST_DIR = "best"
"""Where ``promote`` puts the best transfer-alignment entry. The folder predates the other
problems, and the README and docs run ``policy:agents/zoo/best/model.zip`` as a
transfer-alignment policy, so it stays that problem's."""
BEST_DIR_PROBLEM = "transfer_alignment"


def best_folder(problem: str, zoo: Path = ZOO_DIR) -> Path:
    """The folder of a problem's promoted entry: ``best/`` (:data:`BEST_DIR`) for transfer
    alignment, ``best_<problem>/`` for any other, so that promoting an entry of one problem
    never replaces another problem's best."""
    return zoo / (BEST_DIR if problem == BEST_DIR_PROBLEM else f"{BEST_DIR}_{problem}")


class JudgeCase(StrictModel):
    """One benchmark the entry's policies are judged on (all training seeds, paired)."""

    scenario: str
    overrides: list[str] = Field(default_factory=list)  # --set style, of the scenario
    seed: Annotated[int, Field(ge=0)] = 7000
    trials: Annotated[int, Field(ge=2)] = 64
    metric: str = "state_settled"
    baselines: list[str] = Field(default_factory=lambda: ["kf", "kf-tuned"])
    oracle: bool = True  # also run the truth-tuned oracle schedule (the upper reference)


FAMILIES_SEED = 9000
"""The benchmark seed of a ``families:`` section that names none (a judging seed of transfer
alignment, where the shipped entries' sections are judged)."""


class FamiliesJudge(StrictModel):
    """The judgement on the scenario families: the problem's families study
    (:class:`qkf.core.studies.FamiliesStudy`; transfer alignment's ``qkf study families``) with
    the baselines and the policy of every training seed (``NAME#SEED``) on the same trials, on
    the problem's judged metric. What depends on the problem (its families, judging seeds,
    largest run, reference baseline and defaults) is checked and filled in by
    :func:`families_for` when the entry is loaded."""

    families: Annotated[list[str], Field(min_length=1)] | None = None  # default: every family
    trials: Annotated[int, Field(ge=2)] = 100  # per family
    seed: int = FAMILIES_SEED  # benchmark seed, in the problem's judging range
    baselines: Annotated[list[str], Field(min_length=1)] | None = None  # default: the study's
    metric: str | None = None  # default (and the only one accepted): the problem's
    overrides: list[str] = Field(default_factory=list)  # --set style, of every family

    @field_validator("families")
    @classmethod
    def _once(cls, families: list[str] | None) -> list[str] | None:
        if families is None:
            return None
        twice = sorted({f for f in families if families.count(f) > 1})
        if twice:
            raise ValueError(f"{', '.join(twice)} listed twice")
        return families

    @field_validator("baselines")
    @classmethod
    def _baselines(cls, baselines: list[str] | None) -> list[str] | None:
        labels = [spec_label(b) for b in baselines or []]
        seeded = [b for b in labels if SEED_MARK in b]
        if seeded:
            raise ValueError(
                f"{', '.join(seeded)}: '{SEED_MARK}' marks the training seeds of the entry's "
                "own policy; a baseline needs a label without it"
            )
        twice = sorted({b for b in labels if labels.count(b) > 1})
        if twice:
            raise ValueError(f"{', '.join(twice)} listed twice")
        return baselines


def families_for(section: FamiliesJudge, problem: Problem) -> FamiliesJudge:
    """``section`` checked against ``problem`` and its defaults filled in: every family of the
    problem when none are named, the study preset's baselines, the problem's metric.
    ``ValueError`` naming the field (``families.seed: …``): a problem without a families study,
    a family it does not have, a seed outside its judging range, more trials than it runs, a
    metric other than its judged one, baselines without the study's reference."""
    study = problem.families_study
    if study is None:
        raise ValueError(
            f"families: {problem.name} has no families study; an entry of it is judged with "
            "judging: (qkf judge)"
        )
    known = list(problem.families.judged)
    families = list(section.families) if section.families is not None else known
    unknown = [f for f in families if f not in known]
    if unknown:
        raise ValueError(
            f"families.families: {', '.join(unknown)}: not a family; known: {', '.join(known)}"
        )
    if not problem.seeds.judges(section.seed):
        (low, high), (t_low, t_high) = problem.seeds.judging, problem.seeds.tuning
        raise ValueError(
            f"families.seed: {section.seed} is not a judging seed: judged results use benchmark "
            f"seeds in [{low:,}, {high:,}) (docs/environment.md, 'Seed ranges'); "
            f"[{t_low:,}, {t_high:,}) are the tuning seeds"
        )
    if section.trials > problem.max_trials:
        raise ValueError(
            f"families.trials: {section.trials:,} is more than {problem.name} runs "
            f"({problem.max_trials:,})"
        )
    metric = problem.metric.name
    if section.metric is not None and section.metric != metric:
        raise ValueError(
            f"families.metric: {section.metric}: the families study judges {metric} only"
        )
    baselines = section.baselines if section.baselines is not None else study.default_baselines()
    if study.reference not in [spec_label(b) for b in baselines]:
        raise ValueError(
            f"families.baselines: must include {study.reference} (the policy's score is "
            f"{metric} of {study.reference} / {metric} of the policy)"
        )
    return section.model_copy(update={"families": families, "baselines": baselines,
                                      "metric": metric})  # fmt: skip


class ProblemJudge(StrictModel):
    """The judgement of an entry of any problem: ``qkf judge`` on the problem's families with
    the baselines and the policy of every training seed (``NAME#SEED``) on the same trials.
    What the problem accepts (families, method specs, seed, trials) is checked against it
    before any work (:func:`agents.zoo.commands.judging_plan`)."""

    families: list[str] | None = None  # default: every family of the problem
    baselines: Annotated[list[str], Field(min_length=1)]
    trials: Annotated[int, Field(ge=2)] = 64  # per family
    seed: int | None = None  # default: the problem's first judging seed
    overrides: list[str] = Field(default_factory=list)  # --set style, of every family


class ZooSpec(StrictModel):
    description: str = ""
    train: str
    seeds: Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)] = Field(
        default_factory=lambda: [0, 1, 2]
    )
    judge: JudgeCase | None = None
    also: list[JudgeCase] = Field(default_factory=list)
    families: FamiliesJudge | None = None
    judging: ProblemJudge | None = None

    @model_validator(mode="after")
    def _judged_somewhere(self) -> ZooSpec:
        if self.judge is None and self.families is None and self.judging is None:
            raise ValueError("judge:, families: or judging: required (how the entry is judged)")
        if self.judge is None and self.also:
            raise ValueError("also: needs a judge: case first")
        if len(set(self.seeds)) != len(self.seeds):
            raise ValueError("seeds: a training seed listed twice")
        return self

    def cases(self) -> list[JudgeCase]:
        """The main judging case first, then the others (none for a families-only entry)."""
        return [] if self.judge is None else [self.judge, *self.also]


@dataclass(frozen=True)
class ZooEntry:
    """An entry folder with its spec and training config."""

    name: str
    folder: Path
    spec: ZooSpec
    train_cfg: TrainConfig

    @property
    def problem(self) -> Problem:
        """The problem of its training environment (``qkf.core.problem.problem_of_env``)."""
        return problem_of_env(self.train_cfg.env)

    @property
    def train_source(self) -> str:
        """The training config as ``qkf train`` takes it: a path or a preset name."""
        local = self.folder / self.spec.train
        return str(local) if local.is_file() else self.spec.train

    def seed_dir(self, seed: int) -> Path:
        return self.folder / f"seed_{seed}"

    def model_name(self) -> str:
        return ALGORITHMS[self.train_cfg.agent].model_file

    def seed_model(self, seed: int) -> Path:
        return self.seed_dir(seed) / self.model_name()

    def trained_seeds(self) -> list[int]:
        """The training seeds whose model is in the entry."""
        return [s for s in self.spec.seeds if self.seed_model(s).is_file()]

    def untrained_seeds(self) -> list[int]:
        """The training seeds of ``zoo.yaml`` whose model is not in the entry."""
        return [s for s in self.spec.seeds if not self.seed_model(s).is_file()]

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
    try:
        problem = problem_of_env(train_cfg.env)
    except KeyError as exc:
        raise ConfigError(f"{spec_file}: train: {exc.args[0]}") from None
    if spec.judge is not None and problem.bench is None:
        raise ConfigError(
            f"{spec_file}: judge: runs a problem's bench, which {problem.name} "
            f"({train_cfg.env}) has not got; an entry of it is judged with judging: (qkf judge)"
        )
    if spec.families is not None:
        try:
            spec = spec.model_copy(update={"families": families_for(spec.families, problem)})
        except ValueError as exc:
            raise ConfigError(f"{spec_file}: {exc}") from None
    return ZooEntry(folder.name, folder, spec, train_cfg)


def list_entries(zoo: Path = ZOO_DIR) -> list[ZooEntry]:
    """Every entry of the zoo with a readable spec, by name (``best/`` and ``best_<problem>/``
    are copies, not listed)."""
    entries = []
    for folder in sorted(p for p in zoo.iterdir() if (p / SPEC_FILE).is_file()):
        if folder.name not in {best_folder(p, zoo).name for p in PROBLEMS.names()}:
            entries.append(load_entry(folder.name, zoo))
    return entries
