"""Paired comparisons of methods over the same trials, for any problem (docs/methods.md,
"Per-trial verdicts", "Judging on families").

Every method ran on the same trials; each has one error per trial (an RMS over the trial's
judged window, in any unit common to the methods). Method A against B:

- the pooled ratio ``RMS_A / RMS_B = sqrt(Σ e_A² / Σ e_B²)`` with its percentile interval over
  the same bootstrap resamples of trials for both (paired);
- the per-trial ratios ``e_A / e_B``: their median with its interval over the same resamples,
  the share of trials A wins (``P(improve)``, ties counting half) and the worst decile;
- a verdict: ``better`` when both intervals lie below 1, ``worse`` when both lie above,
  ``unjudged`` with fewer trials than :func:`~qkf.core.stats.min_verdict_trials`, else
  ``inconclusive``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from qkf.core.stats import (
    bootstrap_rms,
    min_verdict_trials,
    per_trial_comparison,
    percentile_interval,
    ratio_side,
    resample_counts,
)


def paired_verdict(lo: float, hi: float, median_lo: float, median_hi: float, judged: bool) -> str:
    """The verdict of a comparison from its two intervals (module docstring); an interval that
    is not known (NaN) never supports a verdict."""
    if not judged:
        return "unjudged"
    pooled, median = ratio_side(lo, hi), ratio_side(median_lo, median_hi)
    if pooled == median != 0:
        return "better" if pooled < 0 else "worse"
    return "inconclusive"


@dataclass(frozen=True)
class VersusRow:
    """``method`` against ``other`` in ``family``: the pooled RMS ratio with its paired
    interval, and the per-trial ratios' median (interval), ``P(improve)`` and worst decile."""

    family: str
    method: str
    other: str
    ratio: float
    lo: float
    hi: float
    median: float = math.nan
    median_lo: float = math.nan
    median_hi: float = math.nan
    p_improve: float = math.nan
    worst_decile: float = math.nan
    judged: bool = True

    @property
    def verdict(self) -> str:
        """``better`` / ``worse`` / ``inconclusive`` / ``unjudged`` (both intervals)."""
        return paired_verdict(self.lo, self.hi, self.median_lo, self.median_hi, self.judged)


def versus_rows(
    family: str,
    errors: Mapping[str, np.ndarray],
    focus: Sequence[str],
    resamples: int,
    level: float,
    seed: int,
) -> list[VersusRow]:
    """Each ``focus`` method against every other method of ``errors`` (method → per-trial
    errors (n,), the same trials in the same order for all), paired over the same
    ``resamples`` bootstrap resamples of trials (seeded by ``seed``) at ``level``. A focus
    method that did not run is skipped."""
    n = next(iter(errors.values())).shape[0]
    counts = resample_counts(n, resamples, seed)
    reps = {m: bootstrap_rms(e**2, counts) for m, e in errors.items()}  # RMS = sqrt(mean e²)
    point = {m: float(np.sqrt(np.mean(e**2))) for m, e in errors.items()}
    judged = n >= min_verdict_trials(level)
    out = []
    for m in focus:
        if m not in errors:
            continue
        for other in errors:
            if other == m:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                lo, hi = percentile_interval(reps[m] / reps[other], level)
                ratio = point[m] / point[other]
            per = per_trial_comparison(errors[m], errors[other], counts, level)
            out.append(
                VersusRow(family, m, other, ratio, float(lo), float(hi), float(per.median),
                          float(per.median_lo), float(per.median_hi), float(per.p_improve),
                          float(per.worst_decile), judged)
            )  # fmt: skip
    return out


__all__ = ["VersusRow", "paired_verdict", "versus_rows"]
