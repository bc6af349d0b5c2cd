"""A trained gyro policy against the constant κ schedules and the level-informed one, per episode
(docs/redundant_gyros.md, "Policies on the noise levels").

Run: ``.venv/bin/python benchmarks/gyro_policy.py MODEL.zip [MODEL2.zip …] --config
gyro_noise_levels --episodes 64 [--frame-stack 4]``.

Each episode is environment seed ``seed + i`` (benchmark seeds, 5,000,000 on: never trained or
validated on). A policy acts deterministically in the gyro environments' batched SB3
environment (observation ``--observation``, v2 by default, stacked ``--frame-stack`` deep as in
training); its criterion is the hindsight's ``J``, the settled mean square of the four
calibrated states over their prior sd (:mod:`qkf.redundant_gyros.hindsight`), accumulated from
the environment's own per-epoch errors. The same episodes are scored for every constant κ of
the action set (:func:`~qkf.redundant_gyros.hindsight.constant_scores`), for the tuned clock
(:mod:`qkf.redundant_gyros.clock`) and for the innovation-based adaptive κ
(:mod:`qkf.redundant_gyros.nis_adaptive`), both tuned on ``--tune-episodes``
episodes from ``--tune-seed`` (tuning seeds, not the judged ones). Printed: policy ÷ best
constant (pooled over the episodes) and policy ÷ level-informed (each episode's own best
constant), as the RMS ratio over episodes with a paired percentile bootstrap 95 % interval, the
median per-episode ratio and the share of episodes the policy wins, and the κ it chose most.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecFrameStack

from envs.redundant_gyros.sb3 import BatchedGyroSB3Env
from qkf.core.stats import bootstrap_rms, percentile_interval, resample_counts
from qkf.redundant_gyros import clock as gyro_clock
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config, nis_adaptive

warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)


def policy_scores(
    model_path: Path, config: str, seeds: np.ndarray, frame_stack: int, observation: str
) -> tuple[np.ndarray, np.ndarray]:
    """``J`` per episode of the policy, and the κ it chose (episodes, periods)."""
    cfg = load_config(config)
    n = seeds.size
    base = BatchedGyroSB3Env(n, cfg, reward="oracle", observation=observation)
    episodes = base.episodes
    env = VecFrameStack(base, frame_stack) if frame_stack > 1 else base
    model = PPO.load(model_path, device="cpu")
    env.seed(int(seeds[0]))  # sub-environment i: seed seeds[0] + i
    obs: Any = env.reset()
    settled = np.array([hs.episode(cfg, int(s)).settled_from for s in seeds])
    total = np.zeros(n)
    kappas = []
    for _ in range(episodes.episode_steps):
        k0 = episodes.k.copy()
        action, _ = model.predict(obs, deterministic=True)
        obs, _, _, _ = env.step(action)
        kappas.append(episodes.actions.kappas[np.asarray(action).reshape(n)])
        total += episodes.settled_square(k0, settled)
    norm = (episodes.n_steps - settled) * 4.0
    return total / norm, np.array(kappas).T


def ratio_row(name: str, num: np.ndarray, den: np.ndarray, counts: np.ndarray) -> str:
    r = float(np.sqrt(np.sum(num) / np.sum(den)))
    boot = bootstrap_rms(num, counts) / bootstrap_rms(den, counts)
    lo, hi = percentile_interval(boot, 0.95)
    per = np.sqrt(num / den)
    return (
        f"| {name} | {r:.3f} [{lo:.3f}, {hi:.3f}] | {np.median(per):.3f} | {np.mean(per < 1):.2f} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs="+", type=Path)
    ap.add_argument("--config", default="gyro_noise_levels")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--seed", type=int, default=5_000_000)
    ap.add_argument("--frame-stack", type=int, default=4)
    ap.add_argument("--observation", default="v2", help="the version the policies saw")
    ap.add_argument("--tune-seed", type=int, default=1_000_000, help="nis-adaptive's tuning")
    ap.add_argument("--tune-episodes", type=int, default=16)
    args = ap.parse_args()
    cfg = load_config(args.config)
    seeds = args.seed + np.arange(args.episodes)
    const = np.stack([hs.constant_scores(hs.episode(cfg, int(s))) for s in seeds])
    best = hs.best_constant(const)
    kappas = np.asarray(cfg.environment.actions.values())
    counts = resample_counts(args.episodes, 10_000, seed=0)
    print(f"{args.config}, {args.episodes} episodes from seed {args.seed}; best constant κ = "
          f"{kappas[best]:.3g}")  # fmt: skip
    tune_seeds = list(args.tune_seed + np.arange(args.tune_episodes))
    rule, _ = nis_adaptive.tune(cfg, tune_seeds)
    adaptive = nis_adaptive.run_rule(cfg, list(seeds), rule)
    print(f"nis-adaptive tuned on seeds {args.tune_seed}…: {rule}")
    clock, _ = gyro_clock.tune(cfg, tune_seeds)
    clocked = np.array([gyro_clock.score(hs.episode(cfg, int(s)), clock) for s in seeds])
    print(f"clock tuned on the same seeds: {clock}")
    print("| A ÷ B | RMS ratio [95 %] | median per episode | P(A wins) |")
    print("|---|---|---|---|")
    print(ratio_row("level-informed ÷ best constant", const.min(axis=1), const[:, best], counts))
    print(ratio_row("nis-adaptive ÷ best constant", adaptive, const[:, best], counts))
    print(ratio_row("clock ÷ best constant", clocked, const[:, best], counts))
    for path in args.models:
        j, chosen = policy_scores(path, args.config, seeds, args.frame_stack, args.observation)
        print(ratio_row(f"`{path}` ÷ best constant", j, const[:, best], counts))
        print(ratio_row(f"`{path}` ÷ level-informed", j, const.min(axis=1), counts))
        print(ratio_row(f"`{path}` ÷ nis-adaptive", j, adaptive, counts))
        print(ratio_row(f"`{path}` ÷ clock", j, clocked, counts))
        values, freq = np.unique(chosen, return_counts=True)
        top = ", ".join(
            f"{v:.3g}: {f / chosen.size:.0%}" for v, f in zip(values, freq, strict=True)
        )
        print(f"κ chosen: {top}")


if __name__ == "__main__":
    main()
