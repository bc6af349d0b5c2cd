"""How much of the ``kf-tuned → hindsight`` gap a policy closes, per scenario family.

The families study of a zoo entry (``qkf zoo evaluate``) runs without ``hindsight`` (about
10 s a trial); an earlier families study on the same benchmark seed holds it. Trials are
reproducible from ``(seed, trial)`` (docs/models.md), so the trials both studies ran are the
same trials: this script pairs them (and checks it, on the methods both ran) and reports, per
family, on ``state_settled``::

    closed = (RMS_kf-tuned − RMS_policy) / (RMS_kf-tuned − RMS_hindsight)

with RMS over the shared trials, and a paired bootstrap 95 % interval over those trials.

    python benchmarks/hindsight_gap.py --study results/zoo/NAME/families \\
        --hindsight results/families_seed9000 --policy 'NAME#0' --out gap.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from qkf.transfer_alignment.metrics import METRIC_COLUMNS
from qkf.transfer_alignment.report import read_trials_csv

METRIC = "state_settled"
REFERENCE = "kf-tuned"
YARDSTICK = "hindsight"


def _trials(folder: Path, family: str) -> dict[str, np.ndarray]:
    """``{method: state_settled per trial}`` of one family's ``trials.csv``, in trial order
    (trials 0 … n − 1 of the benchmark seed); ``{}`` without one."""
    if not (folder / family / "trials.csv").is_file():
        return {}
    j = METRIC_COLUMNS.index(METRIC)
    return {m: v[:, j] for m, v in read_trials_csv(folder / family).items()}


def gap_closed(
    ref: np.ndarray, policy: np.ndarray, yard: np.ndarray, reps: int = 4000, seed: int = 0
) -> tuple[float, float, float]:
    """Point estimate and paired bootstrap 95 % interval of the closed fraction (per-trial
    values of the three methods on the same trials)."""

    def closed(idx: np.ndarray) -> np.ndarray:
        r = np.sqrt(np.mean(ref[idx] ** 2, axis=-1))
        p = np.sqrt(np.mean(policy[idx] ** 2, axis=-1))
        h = np.sqrt(np.mean(yard[idx] ** 2, axis=-1))
        return (r - p) / (r - h)

    n = ref.size
    rng = np.random.default_rng(seed)
    boot = closed(rng.integers(0, n, size=(reps, n)))
    lo, hi = np.nanpercentile(boot, [2.5, 97.5])
    return float(closed(np.arange(n))), float(lo), float(hi)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", type=Path, required=True, help="families study with the policy")
    ap.add_argument("--hindsight", type=Path, required=True, help="families study with hindsight")
    ap.add_argument("--policy", required=True, help="the policy's method label in --study")
    ap.add_argument("--out", type=Path, required=True, help="markdown file to write")
    args = ap.parse_args(argv)
    if args.out.exists():
        print(f"{args.out}: exists; not overwritten", file=sys.stderr)
        return 2
    families = sorted(p.name for p in args.study.iterdir() if (p / "trials.csv").is_file())
    lines = [
        f"# Share of the kf-tuned → hindsight gap closed by `{args.policy}`",
        "",
        f"Policy from `{args.study}`, hindsight from `{args.hindsight}` (same benchmark seed: the "
        "shared trials are the same trials; every method both studies ran agrees on them).",
        "",
        "| family | trials | RMS kf-tuned | RMS policy | RMS hindsight | closed [95 %] |",
        "|---|---|---|---|---|---|",
    ]
    for family in families:
        new, old = _trials(args.study, family), _trials(args.hindsight, family)
        if YARDSTICK not in old or args.policy not in new or REFERENCE not in new:
            continue
        n = min(new[args.policy].size, old[YARDSTICK].size)  # trials 0 … n − 1 of both
        for method in set(new) & set(old):  # the same trials: every common method agrees
            if not np.allclose(new[method][:n], old[method][:n], rtol=1e-9, atol=0.0):
                print(f"{family}: {method} differs between the studies", file=sys.stderr)
                return 1
        ref, pol, yard = new[REFERENCE][:n], new[args.policy][:n], old[YARDSTICK][:n]
        c, lo, hi = gap_closed(ref, pol, yard)
        rms = [float(np.sqrt(np.mean(x**2))) for x in (ref, pol, yard)]
        lines.append(
            f"| {family} | {n} | {rms[0]:.4g} | {rms[1]:.4g} | {rms[2]:.4g} | "
            f"{c:.2f} [{lo:.2f}, {hi:.2f}] |"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
