"""Is ``hindsight`` a bound? Per family of a ``qkf study families`` folder, the share of trials
on which hindsight's ``state_settled`` is at or below (within ``--tolerance``) each other
method's, from the case folders' ``trials.csv``.

    python benchmarks/hindsight_bound.py results/families [--tolerance 0.005]

Acceptance (issue 20): ≥ 95 % of trials for kf, kf-tuned, clock, oracle, alarm-burst and the
shipped policy, on 16 trials of two families at a seed outside every documented range.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED
from qkf.transfer_alignment.results import read_trials_csv


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", type=Path, help="a families study folder (or several)", nargs="+")
    ap.add_argument("--tolerance", type=float, default=0.005)
    args = ap.parse_args()
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    worst = 1.0
    for root in args.study:
        for case in sorted(p.parent for p in root.glob("*/trials.csv")):
            values = read_trials_csv(case)
            if "hindsight" not in values:
                continue
            bound = values["hindsight"][:, j]
            shares = []
            for m, v in values.items():
                if m == "hindsight":
                    continue
                share = float(np.mean(bound <= (1.0 + args.tolerance) * v[:, j]))
                worst = min(worst, share)
                shares.append(f"{m} {share:.2f}")
            print(f"{case.name} ({bound.size} trials): " + ", ".join(shares))
    print(f"smallest share: {worst:.3f}")


if __name__ == "__main__":
    main()
