"""Speed of the benchmark statistics: percentile-bootstrap intervals of every summary metric and
the paired ratios against a baseline, for 1,000 trials × 10 methods × 12 metrics and 10,000
resamples (the target is under 5 s on 2 cores).

Run: ``.venv/bin/python benchmarks/bootstrap_speed.py [--trials N --methods M --resamples R]``.
It prints the time of the computation as ``qkf.transfer_alignment.benchmark`` does it
(resample counts, bootstrap RMS of every method, intervals, paired ratios), best of 3.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from qkf.core.stats import bootstrap_rms, percentile_interval, resample_counts
from qkf.transfer_alignment.benchmark import paired_ratios
from qkf.transfer_alignment.metrics import METRIC_COLUMNS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--methods", type=int, default=10)
    ap.add_argument("--resamples", type=int, default=10_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    labels = [f"m{i}" for i in range(args.methods)]
    values = {m: np.abs(rng.normal(1.0, 0.3, (args.trials, len(METRIC_COLUMNS)))) for m in labels}
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        counts = resample_counts(args.trials, args.resamples, seed=1)
        reps = {m: bootstrap_rms(values[m] ** 2, counts) for m in labels}
        for m in labels:
            percentile_interval(reps[m])
        paired = paired_ratios(labels, values, reps, [labels[0]], 0.95, counts)
        best = min(best, time.perf_counter() - t0)
    print(
        f"{args.trials} trials × {args.methods} methods × {len(METRIC_COLUMNS)} metrics, "
        f"{args.resamples} resamples: {best:.2f} s ({len(paired)} paired ratios)"
    )


if __name__ == "__main__":
    main()
