"""The judging tables of a zoo entry.

``evaluation/zoo_summary.csv`` (the ``judge:``/``also:`` cases), from a benchmark's
``trials.csv``: paired comparisons of every training seed's policy with every baseline, the
share of the kf → oracle gap, and the interquartile mean over training seeds. Its intervals are
paired percentile bootstraps over trials: the same resamples of trials for every method
(:func:`qkf.core.stats.resample_counts`), so "beats" means the interval of the RMS ratio lies
below 1.

``evaluation/zoo_families.csv`` (the ``families:`` section), from the problem's families
study (transfer alignment's ``qkf study families``): per family, rliable's IQM over training
seeds × trials of the score error_reference / error_policy (the judged metric, for transfer
alignment RMS_kf-tuned / RMS_policy of ``state_settled``; above 1 is better) with its
stratified bootstrap interval, the probability of improvement over each baseline, and the
paired ratio of the shipped seed's policy to the yardsticks (:data:`VERSUS`). The numbers are
those of the study's own ``families.md`` (the same functions, :mod:`qkf.core.seed_groups` and
:mod:`qkf.core.versus`, the same bootstrap settings and seed).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from agents.zoo.entry import JudgeCase, ZooEntry
from qkf.core.io import atomic_write_text
from qkf.core.seed_groups import SEED_MARK, seed_statistics
from qkf.core.stats import (
    bootstrap_rms,
    interquartile_mean,
    percentile_interval,
    ratio_side,
    resample_counts,
)
from qkf.core.versus import VersusRow, versus_rows

if TYPE_CHECKING:
    from qkf.core.family_judging import JudgePlan

RESAMPLES = 2000
LEVEL = 0.95
VERSUS = (
    "kf-tuned", "kf-tuned-mixed", "clock", "clock-mixed", "glr", "glr-tuned",
    "glr-tuned-mixed", "alarm-burst", "nis-rule", "nis-rule-tuned", "nis-rule-tuned-mixed",
    "hindsight",
)  # fmt: skip
"""The methods the shipped seed's policy is compared with in ``zoo_families.csv`` (those
that ran): the tuned constant κ and the tuned clock, per family and on the training mixture,
a change detector, the alarm burst, the NIS rule that mimics the policies, and the best κ
schedule found per trial (the end of the headroom)."""


@dataclass(frozen=True)
class JudgeRow:
    """One line of ``zoo_summary.csv``: ``quantity`` of ``policy`` against ``versus``."""

    scenario: str
    seed: int  # benchmark seed
    trials: int
    metric: str
    policy: str  # ``<entry>:s<seed>``, ``<entry>:IQM``; families: ``<entry>``, ``<entry>#<seed>``
    # rms | ratio | median_ratio | trials_won | worst_decile | gap_share (| …_range);
    # families: iqm | p_improve | ratio | median_ratio | trials_won | worst_decile
    quantity: str
    versus: str  # the baseline of a ratio (iqm: kf-tuned; p_improve: the baseline);
    # ``kf→oracle`` for the gap share; "" for rms
    value: float
    lo: float  # NaN where there is no interval (p_improve)
    hi: float
    # ratio: better | worse (the pooled and the median interval on one side of 1) |
    # inconclusive | unjudged (too few trials); iqm: of a score, above 1 better
    verdict: str


def read_metric(trials_csv: Path, metric: str) -> dict[str, np.ndarray]:
    """Per-trial values (trial RMS) of ``metric`` by method label, in trial order."""
    values: dict[str, list[tuple[int, float]]] = {}
    with trials_csv.open(newline="") as f:
        for row in csv.DictReader(f):
            values.setdefault(row["method"], []).append((int(row["trial"]), float(row[metric])))
    return {m: np.array([v for _, v in sorted(rows)]) for m, rows in values.items()}


def judge_summary(entry: ZooEntry, case: JudgeCase, trials_csv: Path) -> list[JudgeRow]:
    """The rows of one judging case (see module docstring)."""
    per_trial = read_metric(trials_csv, case.metric)
    n = len(next(iter(per_trial.values())))
    counts = resample_counts(n, RESAMPLES, case.seed)
    reps = {m: bootstrap_rms(v**2, counts) for m, v in per_trial.items()}
    point = {m: float(np.sqrt(np.mean(v**2))) for m, v in per_trial.items()}
    policies = [m for m in per_trial if m.startswith(f"{entry.name}:s")]
    bases = [b for b in case.baselines if b in per_trial]

    def row(
        policy: str,
        quantity: str,
        versus: str,
        value: float,
        lo: float,
        hi: float,
        verdict: str = "",
    ) -> JudgeRow:
        return JudgeRow(
            case.scenario,
            case.seed,
            n,
            case.metric,
            policy,
            quantity,
            versus,
            value,
            lo,
            hi,
            verdict,
        )

    rows: list[JudgeRow] = []
    share: dict[str, float] = {}
    # the same resamples as ``counts`` (one seed): the paired comparisons of qkf.core.versus
    compared = {
        (v.method, v.other): v
        for v in versus_rows(case.scenario, per_trial, policies, RESAMPLES, LEVEL, case.seed)
    }
    for p in policies:
        lo, hi = percentile_interval(reps[p], LEVEL)
        rows.append(row(p, "rms", "", point[p], float(lo), float(hi)))
        for b in bases:
            rows += comparison_rows(row, compared[p, b])
        if "kf" in per_trial and "oracle" in per_trial and point["kf"] > point["oracle"]:
            rep_share = (reps["kf"] - reps[p]) / (reps["kf"] - reps["oracle"])
            lo, hi = percentile_interval(rep_share, LEVEL)
            share[p] = (point["kf"] - point[p]) / (point["kf"] - point["oracle"])
            rows.append(row(p, "gap_share", "kf→oracle", share[p], float(lo), float(hi)))
    if len(policies) >= 2:  # across training seeds: IQM, with the range of the seeds
        iqm = f"{entry.name}:IQM"
        vals = np.array([point[p] for p in policies])
        rows.append(row(iqm, "rms", "", interquartile_mean(vals), vals.min(), vals.max()))
        for b in bases:
            ratios = vals / point[b]
            rows.append(
                row(iqm, "ratio_range", b, interquartile_mean(ratios), ratios.min(), ratios.max())
            )
        if share:
            s = np.array(list(share.values()))
            rows.append(
                row(iqm, "gap_share_range", "kf→oracle", interquartile_mean(s), s.min(), s.max())
            )
    return rows


def comparison_rows(row: Callable[..., JudgeRow], v: VersusRow) -> list[JudgeRow]:
    """The rows of one paired comparison ``v`` (policy ``v.method`` against ``v.other``): the
    pooled ratio with its verdict (:attr:`~qkf.core.versus.VersusRow.verdict`:
    both intervals), the median per-trial ratio with its interval, the share of trials won and
    the worst decile."""
    nan = float("nan")
    return [
        row(v.method, "ratio", v.other, v.ratio, v.lo, v.hi, v.verdict),
        row(v.method, "median_ratio", v.other, v.median, v.median_lo, v.median_hi),
        row(v.method, "trials_won", v.other, v.p_improve, nan, nan),
        row(v.method, "worst_decile", v.other, v.worst_decile, nan, nan),
    ]


def families_summary(
    entry: ZooEntry, folder: Path, families: list[str], shipped: int | None
) -> list[JudgeRow]:
    """The rows of ``zoo_families.csv`` from the families study in ``folder`` (read by the
    problem's :meth:`~qkf.core.studies.FamiliesStudy.results`), on the problem's judged metric:
    per family, ``iqm`` (policy ``NAME``, versus ``kf-tuned``:
    the score it is normalised by; verdict ``better``/``worse`` when the interval lies above
    or below 1), ``p_improve`` per baseline (no interval: NaN) and the ``ratio`` of the
    shipped seed ``NAME#SEED`` to each method of :data:`VERSUS` that ran (paired interval).
    ``seed`` is the study's benchmark seed; the bootstrap settings are the cases' own."""
    study = entry.problem.families_study
    if study is None:
        raise ValueError(f"{entry.problem.name} has no families study")
    res = study.results(folder, families)
    metric = entry.problem.metric.name
    mine = f"{entry.name}{SEED_MARK}"
    rows: list[JudgeRow] = []
    for family in families:
        errors = res.errors[family]
        n = len(next(iter(errors.values())))
        others = [m for m in errors if not m.startswith(mine)]

        def row(policy: str, quantity: str, versus: str, value: float, lo: float, hi: float,
                verdict: str = "", family: str = family, n: int = n) -> JudgeRow:  # fmt: skip
            return JudgeRow(family, res.seed, n, metric, policy, quantity, versus, value,
                            lo, hi, verdict)  # fmt: skip

        reference = res.references[family]
        for stat in seed_statistics(errors, others, reference, res.level, seed=res.seed):
            if stat["policy"] != entry.name:
                continue
            iqm, lo, hi = (float(str(stat[k])) for k in ("iqm", "iqm_lo", "iqm_hi"))
            side = ratio_side(lo, hi)  # of a score: above 1 is better
            rows.append(row(entry.name, "iqm", reference, iqm, lo, hi,
                            ("inconclusive", "better", "worse")[side]))  # fmt: skip
            for b in others:
                p = stat.get(f"p_improve_{b}")
                if isinstance(p, float):
                    rows.append(row(entry.name, "p_improve", b, p, np.nan, np.nan))
        if shipped is None:
            continue
        label = f"{mine}{shipped}"
        for v in versus_rows(family, errors, [label], res.resamples, res.level, res.seed):
            if v.other in VERSUS:
                rows += comparison_rows(row, v)
    return rows


def judging_summary(
    entry: ZooEntry, plan: JudgePlan, errors: dict[str, dict[str, np.ndarray]]
) -> list[JudgeRow]:
    """The rows of ``zoo_judging.csv`` (a ``judging:`` section, any problem): per family, each
    training seed's policy ``NAME#SEED`` against every baseline, paired over the same trials
    (:func:`qkf.core.versus.versus_rows`, the run's own bootstrap: ``ratio`` with its verdict,
    ``median_ratio``, ``trials_won``, ``worst_decile``), and over the seeds ``NAME:IQM``: the
    interquartile mean of the pooled ratios to each baseline with the seeds' range
    (``ratio_range``)."""
    policies = [p for p in plan.focus if p.startswith(f"{entry.name}#")]
    bases = [b for b in plan.labels if b not in policies]
    metric = plan.problem.metric.name
    rows: list[JudgeRow] = []
    for family in plan.families:
        values = errors[family]

        def row(policy: str, quantity: str, versus: str, value: float, lo: float, hi: float,
                verdict: str = "", family: str = family) -> JudgeRow:  # fmt: skip
            return JudgeRow(family, plan.seed, plan.trials, metric, policy, quantity, versus,
                            value, lo, hi, verdict)  # fmt: skip

        compared = versus_rows(family, values, policies, plan.resamples, plan.level, plan.seed)
        for v in compared:
            if v.other in bases:
                rows += comparison_rows(row, v)
        if len(policies) >= 2:
            for b in bases:
                ratios = np.array([v.ratio for v in compared if v.other == b])
                iqm = interquartile_mean(ratios)
                rows.append(
                    row(f"{entry.name}:IQM", "ratio_range", b, iqm, ratios.min(), ratios.max())
                )
    return rows


def write_summary(rows: list[JudgeRow], path: Path) -> Path:
    """``zoo_summary.csv`` (one line per :class:`JudgeRow`), written atomically."""
    buf = io.StringIO()
    fields = list(JudgeRow.__dataclass_fields__)
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow(
            {k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in asdict(r).items()}
        )
    atomic_write_text(path, buf.getvalue())
    return path


def read_summary(path: Path) -> list[dict[str, str]]:
    """The rows of a ``zoo_summary.csv`` as strings."""
    with path.open(newline="") as f:
        return list(csv.DictReader(f))
