"""What ``qkf zoo train``, ``qkf zoo evaluate`` and ``qkf zoo promote`` do (docs/zoo.md).

* **train**: every training seed of the entry is trained into the work folder
  (``results/zoo/<name>/seed_<s>/``, checkpoints and logs included; a finished run is not
  repeated, an interrupted one goes on from its checkpoint). The model, the exact config, the
  records and the evaluations on the held-out environment seed are copied into the entry's
  ``seed_<s>/``; the seed with the best last evaluation is copied to the entry's top.
* **evaluate**: for each judging case one benchmark runs the baselines, the oracle and the
  policy of *every* training seed on the same trials (benchmark seeds, disjoint from the
  environment seeds the agents were trained on); with a ``families:`` section, the problem's
  families study (:class:`qkf.core.studies.FamiliesStudy`; transfer alignment's
  ``qkf study families``) runs the baselines and
  ``NAME#SEED=policy:…`` of every training seed into ``WORK/families/``. The bench outputs,
  the per-trial tables, the summaries (:mod:`agents.zoo.summary`) and the card go to the work
  folder. The shipped entry (``evaluation/``, ``card.md``, tracked in git) changes only with
  ``update_entry`` (``--update-entry``), so a quick ``--trials 2`` look never rewrites the
  published judgement. Refused before any work (:func:`check_entry`): a seed of ``zoo.yaml``
  without a model, or one trained on another environment than the entry's training config.
* **promote**: copy an entry's shipped policy and card to ``agents/zoo/best/`` (an entry of
  another problem than transfer alignment: ``agents/zoo/best_<problem>/``).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from agents.config import load_train_config
from agents.training import plan_training
from agents.training.records import EVALUATIONS
from agents.zoo.card import write_card
from agents.zoo.entry import ZOO_DIR, FamiliesJudge, JudgeCase, ZooEntry, best_folder
from agents.zoo.summary import (
    LEVEL,
    families_summary,
    judge_summary,
    judging_summary,
    write_summary,
)
from qkf.core.config import ConfigError, read_yaml_mapping
from qkf.core.family_judging import RUN_KIND, JudgePlan
from qkf.core.io import OutputError, atomic_write_bytes, check_output_dir
from qkf.core.method_specs import pick_baselines
from qkf.core.studies import Bench, FamiliesStudy, StudyEvents, StudyRun

PROMOTED = ("config.yaml", "card.md", "SOURCE")
"""What ``promote`` writes into ``best/`` besides the model."""
SEED_FILES = ("config.yaml", "training.json")
"""Copied from a training run into the entry's ``seed_<s>/`` (with the model and
``eval/evaluations.npz`` as ``evaluations.npz``)."""


FAMILIES_DIR = "families"
"""The families study's folder in the work folder (``WORK/families/``)."""
JUDGING_DIR = "judging"
"""The ``qkf judge`` run of a ``judging:`` section in the work folder (``WORK/judging/``)."""
EVALUATION_FILES = (
    "*_trials.csv", "*_summary.md", "zoo_summary.csv", "zoo_families.csv",
    "families_seed*.md", "families_seed*.csv", "zoo_judging.csv", "judging_seed*.md",
    "judging_seed*.csv",
)  # fmt: skip
"""What ``evaluate`` writes into ``evaluation/`` (an earlier run's are removed first, so that
the folder and the card describe one judgement)."""


def _copy(src: Path, dst: Path) -> None:
    atomic_write_bytes(dst, src.read_bytes())


def check_entry(entry: ZooEntry) -> None:
    """Refuse (``ConfigError``) an entry that cannot be judged as ``zoo.yaml`` says: a training
    seed without its model (``seed_<s>/model.*``), or without the ``config.yaml`` beside it,
    or one whose config names another environment (``env:``, its version included) than the
    entry's training config. Reads files only."""
    missing = entry.untrained_seeds()
    if missing:
        listed = ", ".join(str(s) for s in missing)
        raise ConfigError(
            f"{entry.folder}: training seed{'s' if len(missing) > 1 else ''} {listed} of "
            f"zoo.yaml ha{'ve' if len(missing) > 1 else 's'} no model "
            f"(seed_<s>/{entry.model_name()} missing); run qkf zoo train {entry.name} first "
            f"(--seeds {','.join(str(s) for s in missing)} trains only those)"
        )
    want = entry.train_cfg.env
    for s in entry.spec.seeds:
        path = entry.seed_dir(s) / "config.yaml"
        if not path.is_file():
            raise ConfigError(
                f"{path}: missing (the exact training config, copied beside the model by "
                f"qkf zoo train); run qkf zoo train {entry.name} --seeds {s}"
            )
        env = read_yaml_mapping(path, "training config").get("env")
        if env != want:
            raise ConfigError(
                f"{path}: env: {env} but the entry's training config ({entry.spec.train}) "
                f"trains on {want}: seed {s} is a policy of another environment version; "
                f"retrain it (qkf zoo train {entry.name} --seeds {s}) or fix zoo.yaml's train:"
            )


def family_policies(entry: ZooEntry) -> list[str]:
    """``NAME#SEED=policy:PATH`` of every trained seed: the labels the families study pools
    over training seeds (:func:`qkf.core.seed_groups.seed_statistics`)."""
    return [f"{entry.name}#{s}=policy:{entry.seed_model(s)}" for s in entry.trained_seeds()]


def families_section(entry: ZooEntry) -> tuple[FamiliesJudge, FamiliesStudy]:
    """The entry's ``families:`` section (its defaults filled in by ``load_entry``) and its
    problem's families study; ``ConfigError`` without either."""
    fam, study = entry.spec.families, entry.problem.families_study
    if fam is None or study is None or fam.families is None or fam.baselines is None:
        raise ConfigError(f"{entry.folder / 'zoo.yaml'}: no families: section")
    return fam, study


def families_run(
    entry: ZooEntry, trials: int | None, baselines: list[str] | None = None
) -> StudyRun:
    """The entry's families study; ``trials`` replaces the section's own; ``baselines``: only
    these of the section's baselines (``ConfigError`` for one it does not have)."""
    fam, _ = families_section(entry)
    kept = list(fam.baselines or [])
    if baselines is not None:
        try:
            kept = pick_baselines(kept, baselines)
        except ConfigError as exc:
            raise ConfigError(f"{entry.folder / 'zoo.yaml'}: families: {exc}") from None
    return StudyRun(
        tuple(fam.families or []), tuple(kept), tuple(family_policies(entry)), fam.seed,
        trials or fam.trials, tuple(fam.overrides),
    )  # fmt: skip


def case_baselines(entry: ZooEntry, case: JudgeCase, baselines: list[str] | None) -> list[str]:
    """A judging case's baselines, only ``baselines`` among them if given (``ConfigError`` for
    one the case does not have)."""
    if baselines is None:
        return list(case.baselines)
    try:
        return pick_baselines(list(case.baselines), baselines)
    except ConfigError as exc:
        raise ConfigError(f"{entry.folder / 'zoo.yaml'}: {case.scenario}: {exc}") from None


def check_families(
    entry: ZooEntry, work: Path, trials: int | None, baselines: list[str] | None = None
) -> None:
    """Everything the families study would refuse, checked before any work (``ConfigError``):
    the entry's name as a method label, the study (families, methods, seed, every family's
    config with the overrides, the workload, the zoo's interval level: the problem's
    :meth:`~qkf.core.studies.FamiliesStudy.check`), and ``WORK/families/`` (empty, or an
    earlier study, which the run replaces whole at its end)."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", entry.name):
        raise ConfigError(
            f"{entry.folder}: the entry's name {entry.name!r} labels its policies in the "
            "families study (NAME#SEED); use letters, digits, '_', '.', '-' only"
        )
    _, study = families_section(entry)
    run = families_run(entry, trials, baselines)
    try:
        study.check(run, LEVEL)  # the card states the zoo's level
    except ConfigError as exc:
        raise ConfigError(f"{entry.folder / 'zoo.yaml'}: families: {exc}") from None
    try:
        study.check_output(work / FAMILIES_DIR)
    except OutputError as exc:
        raise ConfigError(f"--work: {exc}") from None


def train_entry(
    entry: ZooEntry,
    work: Path,
    seeds: list[int] | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
) -> int | None:
    """Train the entry's seeds (default: all of ``zoo.yaml``), side by side
    (:func:`~agents.training.parallel.train_side_by_side`: ``backend``, ``workers``,
    ``address``); returns the shipped seed. Each seed's network is the one a sequential run
    trains."""
    from agents.training.parallel import train_side_by_side

    chosen_seeds = list(seeds if seeds is not None else entry.spec.seeds)
    plans = []
    for seed in chosen_seeds:
        cfg = load_train_config(entry.train_source, [f"seed={seed}"])
        plan = plan_training(
            cfg, work / f"seed_{seed}", source=f"{entry.train_source} (seed {seed})"
        )
        say(f"seed {seed}: {'already trained' if plan.complete else ', '.join(plan.notes)}")
        plans.append(plan)
    todo = [i for i, p in enumerate(plans) if not p.complete]

    def ship(i: int, model: Path) -> None:
        # into the entry as each seed's result comes back: an interrupted run keeps those done
        seed, run_dir = chosen_seeds[i], plans[i].out
        if not plans[i].complete:
            say(f"seed {seed}: trained")
        dst = entry.seed_dir(seed)
        dst.mkdir(parents=True, exist_ok=True)
        _copy(model, dst / model.name)
        for name in SEED_FILES:
            _copy(run_dir / name, dst / name)
        evaluations = run_dir / EVALUATIONS
        if evaluations.is_file():
            _copy(evaluations, dst / "evaluations.npz")

    for i, plan in enumerate(plans):  # finished earlier: shipped first
        if plan.complete:
            ship(i, plan.model_path)
    train_side_by_side(
        [p for p in plans if not p.complete], backend, workers, address, progress,
        lambda j, model: ship(todo[j], model),
    )  # fmt: skip
    chosen = entry.selected_seed()
    if chosen is not None:
        for name in (entry.model_name(), "config.yaml"):
            _copy(entry.seed_dir(chosen) / name, entry.folder / name)
    write_card(entry)
    return chosen


def policy_methods(entry: ZooEntry) -> list[str]:
    """``LABEL=policy:PATH`` of every trained seed: ``<name>:s<seed>``."""
    return [f"{entry.name}:s{s}=policy:{entry.seed_model(s)}" for s in entry.trained_seeds()]


def entry_bench(entry: ZooEntry) -> Bench:
    """The bench of the entry's problem, which its ``judge:`` cases run (``load_entry`` has
    refused the cases of a problem without one)."""
    bench = entry.problem.bench
    if bench is None:
        raise ConfigError(f"{entry.folder / 'zoo.yaml'}: judge: {entry.problem.name} has no bench")
    return bench


def prepare_case(
    entry: ZooEntry, case: JudgeCase, trials: int | None, baselines: list[str] | None = None
) -> object:
    """One judging benchmark checked before any work (``ConfigError``, ``ValueError``): the
    case's config with its overrides, its baselines (only ``baselines`` among them if given),
    the oracle and every trained seed's policy (``<name>:s<seed>``), and the workload."""
    cfg = entry.problem.load_config(case.scenario, list(case.overrides))
    specs = [
        *case_baselines(entry, case, baselines),
        *(["oracle"] if case.oracle else []),
        *policy_methods(entry),
    ]
    return entry_bench(entry).prepare(cfg, specs, trials or case.trials, case.scenario)


def evaluate_case(
    entry: ZooEntry,
    case: JudgeCase,
    work: Path,
    trials: int | None,
    progress: bool,
    cache: bool = False,
    baselines: list[str] | None = None,
    prepared: object | None = None,
) -> Path:
    """One judging benchmark (``prepared`` by :func:`prepare_case`, or prepared here); returns
    its bench folder (in the work folder)."""
    if prepared is None:
        prepared = prepare_case(entry, case, trials, baselines)
    folder = work / f"judge_{Path(case.scenario).stem}_seed{case.seed}"
    entry_bench(entry).run(prepared, case.seed, folder, progress=progress, cache=cache)
    return folder


def evaluate_families(
    entry: ZooEntry,
    work: Path,
    trials: int | None,
    progress: bool,
    say: Callable[[str], None] = print,
    cache: bool = False,
    baselines: list[str] | None = None,
) -> Path:
    """The entry's families study (the problem's, :class:`~qkf.core.studies.FamiliesStudy`:
    the entry's families, always the shift group, trials, seed, its baselines as the methods
    and ``NAME#SEED=policy:PATH`` per trained seed) into ``WORK/families/``; returns it. A
    family that an earlier, interrupted run there finished with the same config, methods,
    trials and seed is kept, not rerun; anything else of an earlier study there is
    replaced."""
    _, study = families_section(entry)
    run = families_run(entry, trials, baselines)
    out = work / FAMILIES_DIR

    def on_start(i: int, n: int, family: str) -> None:
        say(f"family {i}/{n}: {family}")

    def on_case(family: str, reused: bool) -> None:
        if reused:
            say(f"{family}: finished earlier, kept")

    study.run(run, out, StudyEvents(progress, on_start, on_case), cache)
    return out


def judging_plan(
    entry: ZooEntry, trials: int | None, baselines: list[str] | None = None
) -> JudgePlan:
    """The ``qkf judge`` run of the entry's ``judging:`` section, checked against its problem
    before any work (``ConfigError`` naming ``zoo.yaml``): the section's baselines (only
    ``baselines`` among them if given) and ``NAME#SEED=policy:PATH`` of every trained seed, the
    policies compared with every baseline; ``trials`` replaces the section's own."""
    from qkf.core.family_judging import plan_judging

    section = entry.spec.judging
    where = f"{entry.folder / 'zoo.yaml'}: judging"
    if section is None:
        raise ConfigError(f"{where}: no judging: section")
    kept = list(section.baselines)
    if baselines is not None:
        unknown = [b for b in baselines if b not in kept]
        if unknown:
            raise ConfigError(f"{where}: --baselines: {', '.join(unknown)}: not among "
                              f"{', '.join(kept)}")  # fmt: skip
        kept = [b for b in kept if b in baselines]
    policies = family_policies(entry)
    try:
        return plan_judging(
            entry.problem.name, section.families, [*kept, *policies],
            [p.partition("=")[0] for p in policies], trials or section.trials, section.seed,
            section.overrides, LEVEL,
        )  # fmt: skip
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def evaluate_judging(
    entry: ZooEntry,
    plan: JudgePlan,
    work: Path,
    progress: bool,
    say: Callable[[str], None],
    cache: bool = False,
) -> tuple[Path, dict[str, dict[str, np.ndarray]]]:
    """Run ``plan`` (:func:`judging_plan`) into ``WORK/judging/``, replacing an earlier one
    (``cache``: results read from and stored in the results cache); returns the folder and the
    metric per family, method and trial."""
    from qkf.core.family_judging import judge_rows, run_judging, write_judging
    from qkf.core.results_cache import CacheLog

    def on_family(i: int, n: int, family: str) -> None:
        say(f"family {i}/{n}: {family}")

    logs: dict[str, CacheLog] | None = {} if cache else None
    errors = run_judging(plan, progress, on_family, logs)
    out = work / JUDGING_DIR
    write_judging(plan, errors, judge_rows(plan, errors), out, logs)
    return out, errors


def _clear(folder: Path) -> None:
    """Remove what an earlier ``evaluate`` wrote into ``folder`` (:data:`EVALUATION_FILES`)."""
    for pattern in EVALUATION_FILES:
        for path in folder.glob(pattern):
            if path.is_file():
                path.unlink()


def evaluate_entry(
    entry: ZooEntry,
    work: Path,
    trials: int | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
    update_entry: bool = False,
    cache: bool = False,
    baselines: list[str] | None = None,
) -> Path:
    """Judge every trained seed on every case and, with a ``families:`` section, on the
    scenario families; writes ``evaluation/`` and ``card.md`` into the work folder, and with
    ``update_entry`` into the entry as well. Returns the card's path. ``trials`` replaces the
    trials of every case and of the families. Refused before any work (``ConfigError``): see
    :func:`check_entry` and :func:`check_families`."""
    if not entry.trained_seeds():
        raise FileNotFoundError(f"{entry.folder}: no trained seed (run qkf zoo train first)")
    check_entry(entry)
    prepared = []
    for case in entry.spec.cases():
        try:  # refused before any work; run as prepared
            prepared.append(prepare_case(entry, case, trials, baselines))
        except ValueError as exc:  # a method spec that does not resolve
            raise ConfigError(f"{entry.folder / 'zoo.yaml'}: {case.scenario}: {exc}") from None
    fam = entry.spec.families
    if fam is not None:
        check_families(entry, work, trials, baselines)
    plan = judging_plan(entry, trials, baselines) if entry.spec.judging is not None else None
    if plan is not None:
        try:
            check_output_dir(work / JUDGING_DIR, RUN_KIND, overwrite=None)
        except OutputError as exc:
            raise ConfigError(f"--work: {exc}") from None
    dst = work / "evaluation"
    dst.mkdir(parents=True, exist_ok=True)
    _clear(dst)
    if entry.spec.cases():
        rows = []
        for case, ready in zip(entry.spec.cases(), prepared, strict=True):
            say(f"judging on {case.scenario}, benchmark seed {case.seed}")
            folder = evaluate_case(entry, case, work, trials, progress, cache, baselines, ready)
            stem = f"{Path(case.scenario).stem}_seed{case.seed}"
            _copy(folder / "trials.csv", dst / f"{stem}_trials.csv")
            _copy(folder / "summary.md", dst / f"{stem}_summary.md")
            rows += judge_summary(entry, case, folder / "trials.csv")
        write_summary(rows, dst / "zoo_summary.csv")
    if fam is not None:
        from qkf.core.campaign import case_folder

        run = families_run(entry, trials, baselines)
        shift = entry.problem.families.shift
        judged = [*run.families, *(f for f in shift if f not in run.families)]
        say(
            f"judging on the families {', '.join(run.families)} and the shift group "
            f"{', '.join(shift)}, benchmark seed {fam.seed}"
        )
        study = evaluate_families(entry, work, trials, progress, say, cache, baselines)
        for family in judged:
            _copy(
                study / case_folder(family) / "trials.csv",
                dst / f"families_{family}_seed{fam.seed}_trials.csv",
            )
        _copy(study / "families.md", dst / f"families_seed{fam.seed}.md")
        _copy(study / "families.csv", dst / f"families_seed{fam.seed}.csv")
        rows = families_summary(entry, study, judged, entry.selected_seed())
        write_summary(rows, dst / "zoo_families.csv")
    if plan is not None:
        say(
            f"judging on the {plan.problem.name} families {', '.join(plan.families)}, "
            f"benchmark seed {plan.seed}"
        )
        folder, errors = evaluate_judging(entry, plan, work, progress, say, cache)
        for name in ("versus.md", "versus.csv", "trials.csv"):
            stem, suffix = name.split(".")
            _copy(folder / name, dst / f"judging_seed{plan.seed}_{stem}.{suffix}")
        rows = judging_summary(entry, plan, errors)
        write_summary(rows, dst / "zoo_judging.csv")
    card = write_card(entry, work)
    if update_entry:
        shipped = entry.folder / "evaluation"
        shipped.mkdir(exist_ok=True)
        _clear(shipped)
        for src in sorted(dst.iterdir()):
            if src.is_file():
                _copy(src, shipped / src.name)
        card = write_card(entry)
    return card


def promote(entry: ZooEntry, zoo: Path = ZOO_DIR) -> Path:
    """Copy the entry's shipped policy, config and card to its problem's best folder
    (:func:`best_folder`); returns the folder."""
    best = best_folder(entry.problem.name, zoo)
    model = entry.folder / entry.model_name()
    if not model.is_file():
        raise FileNotFoundError(f"{model}: the entry has no shipped model (qkf zoo train)")
    best.mkdir(exist_ok=True)
    # only what an earlier promote wrote goes: best/ holds nothing else of anyone's
    for name in (*PROMOTED, "model.zip", "model.npz"):
        (best / name).unlink(missing_ok=True)
    for name in (entry.model_name(), *PROMOTED):
        if (entry.folder / name).is_file():
            _copy(entry.folder / name, best / name)
    atomic_write_bytes(best / "SOURCE", f"{entry.name}\n".encode())
    return best


__all__ = [
    "check_entry",
    "check_families",
    "evaluate_case",
    "evaluate_entry",
    "evaluate_families",
    "evaluate_judging",
    "families_run",
    "families_section",
    "family_policies",
    "judging_plan",
    "policy_methods",
    "prepare_case",
    "promote",
    "train_entry",
]
