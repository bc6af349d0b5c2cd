"""Training seeds side by side against one after another (docs/performance.md, "Training seeds
side by side").

Run: ``.venv/bin/python benchmarks/parallel_seeds.py [--config agents/zoo/ppo_mixed_v3/config.yaml]
[--seeds 0,1,2,3,4] [--steps 20000] [--workers N] [--out DIR]``.

Trains the seeds of a training config (``--steps`` replaces its ``total_steps``, so that the
measurement fits in minutes) once in sequence in this process and once side by side
(:func:`agents.training.parallel.train_side_by_side`, local processes), into fresh folders, in
the same sitting. Prints both wall times and their ratio, and checks that every seed's network
is the same bit for bit (exit 1 otherwise).
"""

from __future__ import annotations

import argparse
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from agents.config import load_train_config
from agents.training import TrainPlan, plan_training
from agents.training.parallel import default_workers, train_side_by_side


def weights(model: Path) -> list[np.ndarray]:
    """The network's parameters of an SB3 zip (its ``policy.pth``), in order."""
    import io

    import torch

    with zipfile.ZipFile(model) as z:
        state = torch.load(io.BytesIO(z.read("policy.pth")), map_location="cpu")
    return [v.numpy() for v in state.values()]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", default="agents/zoo/ppo_mixed_v3/config.yaml")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--steps", type=int, default=20_000)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default=None, help="folder for the runs (default: a temporary one)")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    root = Path(args.out or tempfile.mkdtemp(prefix="qkf-seeds-"))

    def plans(kind: str) -> list[TrainPlan]:
        return [
            plan_training(
                load_train_config(args.config, [f"seed={s}", f"total_steps={args.steps}"]),
                root / kind / f"seed_{s}",
            )
            for s in seeds
        ]

    t0 = time.perf_counter()
    serial = train_side_by_side(plans("serial"), workers=1, progress=False)
    t1 = time.perf_counter()
    side = plans("side")
    workers = default_workers(side) if args.workers is None else args.workers
    parallel = train_side_by_side(side, workers=workers, progress=False)
    t2 = time.perf_counter()
    same = all(
        all(np.array_equal(a, b) for a, b in zip(weights(x), weights(y), strict=True))
        for x, y in zip(serial, parallel, strict=True)
    )
    print(
        f"{len(seeds)} seeds × {args.steps} steps of {args.config}: one after another "
        f"{t1 - t0:.0f} s, side by side ({workers} processes) {t2 - t1:.0f} s, ratio "
        f"{(t2 - t1) / (t1 - t0):.2f}; networks identical: {same} ({root})"
    )
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
