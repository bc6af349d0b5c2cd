"""The judging table of a zoo entry (``evaluation/zoo_summary.csv``), from a benchmark's
``trials.csv``: paired comparisons of every training seed's policy with every baseline, the
share of the kf → oracle gap, and the interquartile mean over training seeds.

All intervals are paired percentile bootstraps over trials: the same resamples of trials for
every method (:func:`qkf.core.stats.resample_counts`), so "beats" means the interval of the RMS
ratio lies below 1.
"""

from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from agents.zoo.entry import JudgeCase, ZooEntry
from qkf.core.io import atomic_write_text
from qkf.core.stats import (
    bootstrap_rms,
    interquartile_mean,
    percentile_interval,
    ratio_side,
    resample_counts,
)

RESAMPLES = 2000
LEVEL = 0.95


@dataclass(frozen=True)
class JudgeRow:
    """One line of ``zoo_summary.csv``: ``quantity`` of ``policy`` against ``versus``."""

    scenario: str
    seed: int  # benchmark seed
    trials: int
    metric: str
    policy: str  # ``<entry>:s<seed>`` or ``<entry>:IQM`` over training seeds
    quantity: str  # rms | ratio | gap_share
    versus: str  # the baseline of a ratio; ``kf→oracle`` for the gap share; "" for rms
    value: float
    lo: float
    hi: float
    verdict: str  # ratio: better | worse | inconclusive; otherwise ""


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
        policy: str, quantity: str, versus: str, value: float, lo: float, hi: float
    ) -> JudgeRow:
        verdict = (
            ("inconclusive", "worse", "better")[ratio_side(lo, hi)] if quantity == "ratio" else ""
        )
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
    for p in policies:
        lo, hi = percentile_interval(reps[p], LEVEL)
        rows.append(row(p, "rms", "", point[p], float(lo), float(hi)))
        for b in bases:
            lo, hi = percentile_interval(reps[p] / reps[b], LEVEL)
            rows.append(row(p, "ratio", b, point[p] / point[b], float(lo), float(hi)))
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
