"""Judge methods and policies on a problem's scenario families, for any problem
(``qkf judge``; docs/methods.md, "Judging on families").

For each family (a preset of the problem), every method runs on the same trials of one judging
seed (:meth:`~qkf.core.problem.Problem.trial_errors`); each ``focus`` method is then compared
with every other on that family by :func:`qkf.core.versus.versus_rows`: the pooled RMS ratio
and the median per-trial ratio with paired bootstrap intervals, ``P(improve)``, the worst
decile and a verdict. Everything that can be refused is refused by :func:`plan_judging` before
any work: the problem, the families and their configs, the method specs, the focus labels, the
workload and a seed outside the problem's judging range (a run judged on tuning seeds would
judge the tuned methods on the trials they were tuned on). On a shift family the tuned methods
tune on :attr:`~qkf.core.problem.Families.shift_tuned_on`'s tuning trials, where the problem
names one: none is told the shift it is judged under.

Written by :func:`write_judging` (all files at once, :func:`~qkf.core.io.staged_directory`):

- ``trials.csv``: ``family, trial`` and one column per method, the judged metric per trial;
- ``versus.csv``: one row per family, focus method and other method (:data:`VERSUS_COLUMNS`);
- ``versus.md``: the same as tables, one per family;
- ``run.json``: the problem, families, method specs, trials, seed, bootstrap and overrides, and
  what the results cache gave per family and method (``cache``; docs/caching.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.config import ConfigError
from qkf.core.io import atomic_write_csv, atomic_write_text, staged_directory
from qkf.core.manifest import manifest, write_manifest
from qkf.core.problem import PROBLEMS, Problem, TrialRequest
from qkf.core.registry import RegistryError
from qkf.core.results_cache import CacheLog, cache_enabled
from qkf.core.versus import VersusRow, versus_rows

RUN_KIND = "judge"
VERSUS_COLUMNS: tuple[str, ...] = (
    "family", "method", "other", "ratio", "ratio_lo", "ratio_hi", "median_ratio", "median_lo",
    "median_hi", "p_improve", "worst_decile", "verdict",
)  # fmt: skip


@dataclass(frozen=True)
class JudgePlan:
    """A checked judging run (:func:`plan_judging`)."""

    problem: Problem
    families: list[str]
    configs: list[Any]  # each family's config, with the overrides
    tuning_configs: list[Any]  # the config each family's tuned methods tune on (None: its own)
    specs: list[str]  # method specs, as given
    labels: list[str]  # what they are reported under
    focus: list[str]
    trials: int
    seed: int
    level: float = 0.95
    resamples: int = 2000
    overrides: list[str] = field(default_factory=list)


def plan_judging(
    problem: str,
    families: Sequence[str] | None,
    specs: Sequence[str],
    focus: Sequence[str] | None = None,
    trials: int = 64,
    seed: int | None = None,
    overrides: Sequence[str] = (),
    level: float = 0.95,
    resamples: int = 2000,
) -> JudgePlan:
    """Check everything before any work (``ConfigError`` naming the option and the value).

    ``families`` None: every family of the problem (:meth:`~qkf.core.problem.Families.all`);
    ``focus`` None: every method against every other; ``seed`` None: the first judging seed.
    """
    try:
        prob = PROBLEMS[problem]
    except RegistryError as exc:
        raise ConfigError(f"problem: {exc}") from None
    chosen = list(families) if families is not None else list(prob.families.all())
    known = prob.families.all()
    unknown = [f for f in chosen if f not in known]
    if unknown or not chosen:
        raise ConfigError(
            f"--families: {', '.join(unknown) or 'none given'}: not a family of {prob.name}; "
            f"known: {', '.join(known)}"
        )
    if len(set(chosen)) < len(chosen):
        raise ConfigError("--families: a family listed twice")
    if not 2 <= trials <= prob.max_trials:
        raise ConfigError(f"--trials: {trials}; must be in [2, {prob.max_trials:,}]")
    if not (0.5 <= level < 1.0 and resamples >= 100):
        raise ConfigError("the bootstrap: level in [0.5, 1), resamples ≥ 100")
    seed = prob.seeds.judging[0] if seed is None else seed
    if not prob.seeds.judges(seed, trials):
        low, high = prob.seeds.judging
        drawn = (
            f"{trials} trials of seed {seed} draw seeds [{seed:,}, {seed + trials:,}), "
            "not all of them judging seeds"
            if prob.seeds.seed_per_trial and prob.seeds.judges(seed)
            else f"{seed} is not a judging seed"
        )
        raise ConfigError(
            f"--seed: {drawn} of {prob.name}: [{low:,}, {high:,}) "
            f"(tuning seeds: [{prob.seeds.tuning[0]:,}, {prob.seeds.tuning[1]:,}))"
        )
    if not specs:
        raise ConfigError("--methods: no method given")
    try:
        labels = prob.method_labels(list(specs))
    except ValueError as exc:
        raise ConfigError(f"--methods: {exc}") from None
    if len(labels) < 2:
        raise ConfigError("--methods: at least two methods (a comparison needs another)")
    picked = list(labels) if focus is None else list(focus)
    missing = [f for f in picked if f not in labels]
    if missing:
        raise ConfigError(
            f"--focus: {', '.join(missing)}: not among the methods' labels {', '.join(labels)}"
        )
    configs, tuning = [], []
    for fam in chosen:
        tuned_on = prob.families.tuning_family(fam)
        try:
            cfg = prob.load_config(fam, list(overrides))
            prob.check_workload(cfg, trials)
            prob.check_methods(cfg, list(specs))
            tuning.append(None if tuned_on == fam else prob.load_config(tuned_on, list(overrides)))
        except ConfigError as exc:
            raise ConfigError(f"family {fam}: {exc}") from None
        configs.append(cfg)
    return JudgePlan(
        prob, chosen, configs, tuning, list(specs), labels, picked, trials, seed, level,
        resamples, list(overrides),
    )  # fmt: skip


def run_judging(
    plan: JudgePlan,
    progress: bool = False,
    on_family: Callable[[int, int, str], None] | None = None,
    cache: dict[str, CacheLog] | None = None,
) -> dict[str, dict[str, np.ndarray]]:
    """Family → label → the judged metric per trial (trials,); ``on_family(i, n, family)``
    before each family. ``cache``: use the results cache (unless ``$QKF_NO_CACHE``), each
    family's lookups logged into ``cache[family]`` (None: compute everything)."""
    out = {}
    logs = cache if cache_enabled() else None
    runs = zip(plan.families, plan.configs, plan.tuning_configs, strict=True)
    for i, (fam, cfg, tuning_cfg) in enumerate(runs, start=1):
        if on_family is not None:
            on_family(i, len(plan.families), fam)
        log = None if logs is None else logs.setdefault(fam, CacheLog())
        request = TrialRequest(tuple(plan.specs), plan.trials, plan.seed, tuning_cfg, progress, log)
        out[fam] = plan.problem.trial_errors(cfg, request)
    return out


def judge_rows(plan: JudgePlan, errors: dict[str, dict[str, np.ndarray]]) -> list[VersusRow]:
    """Each focus method against every other method, per family (bootstrap seeded by the
    judging seed: the same run gives the same table)."""
    rows: list[VersusRow] = []
    for fam in plan.families:
        rows += versus_rows(fam, errors[fam], plan.focus, plan.resamples, plan.level, plan.seed)
    return rows


def _cell(v: float) -> object:
    return "" if math.isnan(v) else v


def versus_markdown(plan: JudgePlan, rows: Sequence[VersusRow]) -> str:
    """``versus.md``: one table per family (ratios below 1: the focus method is better)."""
    pct = f"{100 * plan.level:g} %"
    lines = [
        f"# {plan.problem.name}: {plan.problem.metric.name}, {plan.trials} trials per family, "
        f"seed {plan.seed}",
        "",
        f"{plan.problem.metric.description}. Ratios of method ÷ other: pooled RMS ratio and "
        f"median per-trial ratio with paired bootstrap {pct} intervals; below 1 the method is "
        "better. A verdict needs both intervals on the same side of 1.",
    ]
    for fam in plan.families:
        lines += ["", f"## {fam}", ""]
        tuned_on = plan.problem.families.tuning_family(fam)
        if tuned_on != fam:  # a shift family: say what the tuned labels stand for
            lines += [
                f"A shift family: the tuned methods tuned on `{tuned_on}`'s tuning trials, "
                "never on this family (their labels are unchanged).",
                "",
            ]
        lines += [
            f"| method ÷ other | RMS ratio [{pct}] | median ratio [{pct}] | P(improve) | "
            "worst decile | verdict |",
            "|---|---|---|---|---|---|",
        ]
        for r in rows:
            if r.family == fam:
                lines.append(
                    f"| {r.method} ÷ {r.other} | {r.ratio:.3f} [{r.lo:.3f}, {r.hi:.3f}] | "
                    f"{r.median:.3f} [{r.median_lo:.3f}, {r.median_hi:.3f}] | "
                    f"{r.p_improve:.2f} | {r.worst_decile:.3f} | {r.verdict} |"
                )
    return "\n".join(lines) + "\n"


def write_judging(
    plan: JudgePlan,
    errors: dict[str, dict[str, np.ndarray]],
    rows: Sequence[VersusRow],
    out: str | Path,
    cache: dict[str, CacheLog] | None = None,
) -> Path:
    """Write the run's files into ``out`` (module docstring), replacing an earlier judging run
    there whole; returns ``out``. ``cache``: the results-cache lookups of :func:`run_judging`,
    recorded in ``run.json`` (``cache``: per family and method, the count of hits, misses,
    damaged entries and results not cached; ``"off"`` without)."""
    with staged_directory(out) as stage:
        trial_rows = [
            [fam, t, *(float(errors[fam][label][t]) for label in plan.labels)]
            for fam in plan.families
            for t in range(plan.trials)
        ]
        atomic_write_csv(stage / "trials.csv", ["family", "trial", *plan.labels], trial_rows)
        atomic_write_csv(
            stage / "versus.csv",
            VERSUS_COLUMNS,
            [
                [r.family, r.method, r.other, *map(_cell, (r.ratio, r.lo, r.hi, r.median,
                 r.median_lo, r.median_hi, r.p_improve, r.worst_decile)), r.verdict]
                for r in rows
            ],
        )  # fmt: skip
        atomic_write_text(stage / "versus.md", versus_markdown(plan, rows))
        write_manifest(
            stage,
            manifest(
                RUN_KIND,
                {"overrides": plan.overrides},
                problem=plan.problem.name,
                metric=plan.problem.metric.name,
                families=plan.families,
                methods=dict(zip(plan.labels, plan.specs, strict=True)),
                focus=plan.focus,
                tuned_on={fam: plan.problem.families.tuning_family(fam) for fam in plan.families},
                trials=plan.trials,
                seed=plan.seed,
                bootstrap={"level": plan.level, "resamples": plan.resamples},
                cache=_cache_record(cache),
            ),
        )
    return Path(out)


def _cache_record(cache: dict[str, CacheLog] | None) -> object:
    """What ``run.json`` says of the results cache: ``"off"``, or per family the lookups of each
    method and the damaged entries found (recomputed)."""
    if not cache:
        return "off"
    return {
        fam: {"lookups": log.counts, **({"damaged": log.problems} if log.problems else {})}
        for fam, log in cache.items()
    }


__all__ = [
    "RUN_KIND",
    "VERSUS_COLUMNS",
    "JudgePlan",
    "judge_rows",
    "plan_judging",
    "run_judging",
    "versus_markdown",
    "write_judging",
]
