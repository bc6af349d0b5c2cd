"""Saved κ policies compared on validation trials (never judging seeds): the ablations of
docs/zoo.md ("Training on the mixture") are read from it.

On ``--trials`` trials of ``mixed_random`` drawn from a validation bench seed (default
2,000,000: docs/environment.md, "Seed ranges"), per policy, on ``state_settled``:

* the pooled ratio ``RMS_policy / RMS_kf`` (κ = 1) and ``RMS_policy / RMS_best`` (the best
  constant κ of the action set on the same trials, chosen with the truth);
* the mean over trials of ``1 − MS_policy / MS_kf``, the return of the ``relative_state_gain``
  reward the policies are trained on;
* the pooled ratio to kf on the steady trials (the mixture's ``steady_random`` component).

    python benchmarks/validate_policies.py --trials 64 \\
        'stack4#0=agents/zoo/ppo_mixed_v3/seed_0/model.zip' 'memoryless#0=DIR/model.zip'
"""

from __future__ import annotations

import argparse

import numpy as np

from agents.policy import run_policy
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.judging import estimate_scores
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.scenario import family_names, simulate

VALIDATION_SEED = 2_000_000


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("policies", nargs="+", help="LABEL=PATH of saved models")
    ap.add_argument("--trials", type=int, default=64)
    ap.add_argument("--seed", type=int, default=VALIDATION_SEED, help="a validation seed")
    args = ap.parse_args(argv)
    if not 2_000_000 <= args.seed < 3_000_000:
        ap.error("--seed: validation seeds are [2,000,000, 3,000,000)")
    cfg = load_config("mixed_random")
    data = simulate(cfg, args.seed, args.trials)

    def constant(k: float) -> np.ndarray:  # per-trial mean square of state_settled, κ fixed
        est = run_schedule(cfg, data, np.full((args.trials, data.n_epochs), k)).est
        return estimate_scores(cfg, est, data) ** 2

    ms = {float(k): constant(k) for k in cfg.adaptive.actions.values()}
    kf = ms[1.0]
    best_k = min(ms, key=lambda k: float(np.mean(ms[k])))
    names = family_names(cfg)
    assert data.family is not None
    steady = np.array([names[i] == "steady_random" for i in data.family])
    print(
        f"{args.trials} trials of mixed_random, seed {args.seed} ({int(steady.sum())} steady); "
        f"best constant κ {best_k:.3g}: ÷ kf {np.sqrt(np.mean(ms[best_k]) / np.mean(kf)):.4f}"
    )
    print("| policy | ÷ kf | ÷ best constant | mean 1 − MS/MS_kf | steady ÷ kf |")
    print("|---|---|---|---|---|")
    for spec in args.policies:
        label, path = spec.split("=", 1)
        m = estimate_scores(cfg, run_policy(cfg, data, path).est, data) ** 2
        print(
            f"| {label} | {np.sqrt(np.mean(m) / np.mean(kf)):.4f} | "
            f"{np.sqrt(np.mean(m) / np.mean(ms[best_k])):.4f} | {np.mean(1 - m / kf):.4f} | "
            f"{np.sqrt(np.mean(m[steady]) / np.mean(kf[steady])):.4f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
