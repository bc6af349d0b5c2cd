"""Cost and convergence of the hindsight search (docs/methods.md, "Hindsight").

Run: ``.venv/bin/python benchmarks/hindsight_cost.py [--scenario thermal_snap_random]
[--trials 4] [--seed 5000000] [--set adaptive.hindsight.focus_s=null]``.

Prints the seconds per trial of the whole method (search and final run), the filter work it
spent (trial-epochs per trial) and the rate that makes, next to the rate of one plain filter
run over the same trials (the machine's speed at the time: on a shared machine both move
together), then the score after each stage of the search, mean and per trial.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods.base import action_values, new_filter
from qkf.transfer_alignment.methods.hindsight import hindsight_plan
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.methods.schedule_search import search
from qkf.transfer_alignment.scenario import simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--scenario", default="thermal_snap_random", help="preset name or YAML path")
    ap.add_argument("--trials", type=int, default=4)
    ap.add_argument("--seed", type=int, default=5_000_000)
    ap.add_argument("--set", action="append", default=[], help="config override key=value")
    args = ap.parse_args()
    cfg = load_config(args.scenario, args.set)
    data = simulate(cfg, args.seed, args.trials)
    b, n, a = data.n_trials, data.n_epochs, action_values(cfg).size
    plan = hindsight_plan(cfg)
    hc = cfg.adaptive.hindsight
    print(
        f"{cfg.name}: {b} trials × {n} epochs, seed {args.seed}; {a} actions, period "
        f"{hc.period_s:g} s, blocks {hc.blocks_s} s, passes {hc.passes}, focus {hc.focus_s} s"
    )
    search(cfg, simulate(cfg, args.seed, 1), plan)  # compile the kernel, warm the caches

    # the plain filter's rate over the same trials, batched as the search batches them
    kf = new_filter(cfg, data, a)
    rep = np.repeat(np.arange(b), a)
    t0 = time.perf_counter()
    kf.step(data.gyro[rep], data.ads_q[rep], data.ads_rate[rep], data.has_meas, 1.0)
    plain = (time.perf_counter() - t0) / (b * a * n)

    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    res = search(cfg, data, plan)
    run_schedule(cfg, data, res.kappa)  # the method's final run, as hindsight() does it
    total = time.perf_counter() - t0
    print(
        f"{total / b:.2f} s per trial ({res.seconds / b:.2f} s search); "
        f"{res.runs / b:.0f} rollouts, {res.trial_epochs / b / 1e6:.2f} M trial-epochs per "
        f"trial; {res.seconds / res.trial_epochs * 1e6:.2f} µs per trial-epoch searched vs "
        f"{plain * 1e6:.2f} µs plain filter; load average {load0:.1f} → {os.getloadavg()[0]:.1f}"
    )
    print(f"{'stage':>10s} {'mean':>9s}  per trial ({cfg.adaptive.tuned.metric})")
    for stage, col in zip(res.stages, res.scores.T, strict=True):
        print(f"{stage:>10s} {col.mean():9.4f}  " + " ".join(f"{v:8.4f}" for v in col))


if __name__ == "__main__":
    main()
