"""Cost of the adaptive methods per filter-step, relative to the fixed-Q KF, in one run.

Run: ``.venv/bin/python benchmarks/method_cost.py [--trials 64] [--config paper]``.

Every method filters the same simulated trials; the time of each (best of ``--repeats``) is
divided by trials × epochs and printed with its ratio to ``kf``. ``kf-tuned`` is timed after
its one-off tuning (cached per process), so its ratio is the filtering alone.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods import BUILTIN_METHODS, METHODS, prepare
from qkf.transfer_alignment.scenario import simulate

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", default="paper", help="preset name or YAML path")
    ap.add_argument("--trials", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], help="config override key=value")
    args = ap.parse_args()
    cfg = load_config(args.config, args.set)
    data = simulate(cfg, 0, args.trials)
    # preparing (the tuned KF's tuning) is a one-off cost, kept out of the per-step figures
    methods = {name: prepare(METHODS[name], cfg) for name in BUILTIN_METHODS}
    steps = data.n_trials * data.n_epochs
    print(f"config {cfg.name}: {data.n_trials} trials × {data.n_epochs} epochs")
    cost: dict[str, float] = {}
    for name, fn in methods.items():
        fn(cfg, simulate(cfg, 0, 1))  # compile and warm up
        best = np.inf
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            fn(cfg, data)
            best = min(best, time.perf_counter() - t0)
        cost[name] = best / steps
    for name, c in cost.items():
        print(
            f"{name:10s} {c * 1e6:8.2f} us per filter-step   cost_ratio_vs_kf: {c / cost['kf']:.2f}"
        )


if __name__ == "__main__":
    main()
