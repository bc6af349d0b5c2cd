"""Verdicts per trial as well as pooled, and none from a handful of trials (issue 33, item 2;
docs/methods.md "Per-trial verdicts")."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

from qkf.core.stats import (
    bootstrap_median,
    median_interval_coverage,
    min_verdict_trials,
    per_trial_comparison,
    percentile_interval,
    resample_counts,
    trial_ratios,
)
from qkf.transfer_alignment.benchmark import paired_verdict, run_benchmark
from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.methods import NamedMethod
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.methods.fixed import run_fixed
from qkf.transfer_alignment.report import summary_markdown
from qkf.transfer_alignment.results import write_bench
from qkf.transfer_alignment.scenario import ScenarioData

SEED = 5_300_000  # outside every documented seed range (docs/environment.md)


def _kappa_100(cfg: Config, data: ScenarioData) -> MethodOutput:
    return run_fixed(cfg, data, 100.0)


KAPPA_100 = NamedMethod("kf-k100", _kappa_100)


@pytest.mark.parametrize("n", [7, 10])
def test_bootstrap_median_is_the_median_of_each_resample(n: int) -> None:
    x = np.random.default_rng(n).normal(size=(n, 3))
    counts = resample_counts(n, 50, seed=1)
    got = bootstrap_median(x, counts)
    for r in range(counts.shape[0]):
        drawn = np.repeat(x, counts[r].astype(int), axis=0)
        assert np.allclose(got[r], np.median(drawn, axis=0), rtol=0, atol=0)


def test_per_trial_comparison_by_hand() -> None:
    a = np.array([1.0, 2.0, 3.0, 8.0, 5.0])
    b = np.array([2.0, 2.0, 2.0, 2.0, 10.0])  # ratios 0.5, 1, 1.5, 4, 0.5
    counts = resample_counts(5, 200, seed=3)
    per = per_trial_comparison(a[:, None], b[:, None], counts, 0.95)
    assert per.median[0] == 1.0
    assert per.p_improve[0] == pytest.approx((2 + 0.5) / 5)  # two wins, one tie
    assert per.worst_decile[0] == pytest.approx(np.percentile([0.5, 1, 1.5, 4, 0.5], 90))
    lo, hi = percentile_interval(bootstrap_median(a / b, counts), 0.95)
    assert (per.median_lo[0], per.median_hi[0]) == (lo, hi)


def test_last_bit_differences_are_ties_not_wins() -> None:
    """One schedule run by two compiled twins differs in the last bits: no win either way;
    a difference beyond the tie tolerance is one."""
    base = np.array([1.0, 2.0, 3.0, 4.0])[:, None]
    twin = base * np.array([1 - 1e-15, 1 + 1e-15, 1 - 1e-12, 1.0])[:, None]
    counts = resample_counts(4, 100, seed=1)
    assert per_trial_comparison(twin, base, counts, 0.95).p_improve[0] == 0.5
    apart = base * np.array([1 - 1e-6, 1 + 1e-6, 1 - 1e-6, 1.0])[:, None]
    assert per_trial_comparison(apart, base, counts, 0.95).p_improve[0] == (2 + 0.5) / 4


def test_a_lost_trial_counts_against_whoever_lost_it() -> None:
    r = trial_ratios(np.array([np.nan, 1.0, np.inf, 2.0]), np.array([1.0, np.nan, np.nan, 4.0]))
    assert r.tolist() == [math.inf, 0.0, 1.0, 0.5]


def test_verdict_needs_both_intervals_on_one_side() -> None:
    assert paired_verdict(0.8, 0.9, 0.7, 0.95, True) == "better"
    assert paired_verdict(1.1, 1.3, 1.05, 1.2, True) == "worse"
    # pooled below 1 but the typical trial is not (a few trials carry the pooled number)
    assert paired_verdict(0.8, 0.9, 0.95, 1.6, True) == "inconclusive"
    assert paired_verdict(0.8, 0.9, 1.1, 1.6, True) == "inconclusive"
    assert paired_verdict(0.8, 0.9, math.nan, math.nan, True) == "inconclusive"
    assert paired_verdict(0.8, 0.9, 0.7, 0.95, False) == "unjudged"


def test_median_interval_coverage_matches_simulation() -> None:
    """The exact coverage formula against a simulation of the same order-statistic interval
    (the percentile interval of the bootstrap median lands on order statistics)."""
    n, level, sims = 9, 0.95, 4000
    rng = np.random.default_rng(11)
    counts = resample_counts(n, 4000, seed=5)
    hits = 0
    for _ in range(sims):
        x = rng.standard_normal(n)  # true median 0
        lo, hi = percentile_interval(bootstrap_median(x, counts), level)
        hits += bool(lo <= 0.0 <= hi)
    p = median_interval_coverage(n, level)
    sd = math.sqrt(p * (1 - p) / sims)
    # the interval's ends interpolate between order statistics, so allow a little beyond 4σ
    assert abs(hits / sims - p) < 4 * sd + 0.01


def test_minimum_trials_is_derived_from_coverage() -> None:
    need = min_verdict_trials(0.95)
    floor = 0.95 - 0.05
    assert median_interval_coverage(need - 1, 0.95) < floor
    assert all(median_interval_coverage(n, 0.95) >= floor for n in range(need, 200))
    assert need == 15  # documented in docs/methods.md; the test above derives it


def test_no_verdict_marks_from_three_trials(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cfg = load_config("paper", ["scenario.duration_s=600"])
    res = run_benchmark(cfg, ["kf", KAPPA_100], trials=3, seed=SEED, progress=False)
    text = summary_markdown(res)
    assert "No verdict marks: 3 trial(s), fewer than the 15" in text
    assert "↓" not in text and "↑" not in text
    write_bench(res, tmp_path / "out")
    with (tmp_path / "out" / "paired.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and {r["verdict"] for r in rows} == {"unjudged"}
    for col in ("median_ratio", "median_lo", "median_hi", "p_improve", "worst_decile"):
        assert all(r[col] != "" for r in rows)


def test_verdict_marks_with_enough_trials(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """κ = 100 on a steady run is worse than κ = 1 on every trial: with 16 trials the verdict
    is given, and it is 'worse' on the whole-state metric."""
    cfg = load_config("paper", ["scenario.duration_s=600"])
    res = run_benchmark(cfg, ["kf", KAPPA_100], trials=16, seed=SEED, progress=False)
    (p,) = [p for p in res.paired if p.method == "kf-k100" and p.metric == "state_settled"]
    assert p.judged and p.verdict == "worse"
    assert p.p_improve < 0.2 and p.median > 1.0 and p.worst_decile >= p.median
    assert "No verdict marks" not in summary_markdown(res)
