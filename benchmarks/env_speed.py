"""Environment throughput: the single env against the batched vector env, in one run.

Run: ``.venv/bin/python benchmarks/env_speed.py``. Prints env-steps per second and the
filter-steps per second they imply (one env step = one decision period of 10 filter epochs),
and the ratio of each vector env to the single env (target: ≥ 10 at 256 envs).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from envs import BatchedTransferAlignmentEnv, TransferAlignmentEnv


def rate(step, n_envs: int, seconds: float) -> float:  # type: ignore[no-untyped-def]
    """Env-steps per second of ``step()`` over about ``seconds`` (after one warm-up call)."""
    step()
    calls, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        step()
        calls += 1
    return calls * n_envs / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", default="64,256")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--ppo-steps", type=int, default=8192, help="0 skips the PPO measurement")
    args = ap.parse_args()
    env = TransferAlignmentEnv()
    env.reset(seed=0)
    period = env._driver.core.period
    rng = np.random.default_rng(0)

    def single_step() -> None:
        _, _, term, trunc, _ = env.step(int(rng.integers(11)))
        if term or trunc:
            env.reset()

    base = rate(single_step, 1, args.seconds)
    print(f"single env: {base:10,.0f} env-steps/s  {base * period:12,.0f} filter-steps/s")
    for n in (int(s) for s in args.sizes.split(",")):
        vec = BatchedTransferAlignmentEnv(n)
        vec.reset(seed=0)
        r = rate(lambda v=vec, n=n: v.step(rng.integers(0, 11, n)), n, args.seconds)
        print(
            f"vector {n:4d}: {r:10,.0f} env-steps/s  {r * period:12,.0f} filter-steps/s  "
            f"ratio_vs_single: {r / base:.1f}"
        )
    if args.ppo_steps:
        ppo_fps(args.ppo_steps)


def ppo_fps(steps: int) -> None:
    """Training throughput (env steps/s, end to end): PPO on one env and on the batched vec
    env, and RecurrentPPO (sb3-contrib, LSTM policy, default sizes) and PPO on the zoo's set-up
    (v2 observation, ``misalignment_gain`` with its reference filter, ``thermal_snap_random``);
    for the last, the share of PPO's wall time spent stepping the environment (goal ≤ 15 %)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from envs.transfer_alignment.sb3 import BatchedTransferAlignmentSB3Env

    torch.set_num_threads(1)

    def zoo_env() -> BatchedTransferAlignmentSB3Env:
        return BatchedTransferAlignmentSB3Env(
            16, "thermal_snap_random", reward="misalignment_gain", observation="v2"
        )

    from sb3_contrib import RecurrentPPO

    for name, env in (
        ("PPO, 1 env (DummyVecEnv)", DummyVecEnv([TransferAlignmentEnv])),
        ("PPO, 16 envs (batched VecEnv)", BatchedTransferAlignmentSB3Env(16)),
        ("RecurrentPPO, 16 envs, v2 + misalignment_gain", zoo_env()),
        ("PPO, 16 envs, v2 + misalignment_gain", zoo_env()),
    ):
        algo = RecurrentPPO if name.startswith("Recurrent") else PPO
        policy = "MlpLstmPolicy" if algo is RecurrentPPO else "MlpPolicy"
        n_steps = max(64, 2048 // env.num_envs)
        model = algo(policy, env, n_steps=n_steps, seed=0, device="cpu")
        t0 = time.perf_counter()
        model.learn(steps)
        print(f"{name}: {steps / (time.perf_counter() - t0):8,.0f} env-steps/s")
    ppo = steps / (time.perf_counter() - t0)  # the last one: PPO on the zoo's set-up
    env = zoo_env()
    env.seed(0)
    env.reset()
    rng = np.random.default_rng(1)
    alone = rate(lambda: env.step(rng.integers(0, 11, 16)), 16, 3.0)
    print(
        f"v2 + misalignment_gain env alone: {alone:8,.0f} env-steps/s; share of PPO wall time "
        f"in the environment: {ppo / alone:.0%}"
    )


if __name__ == "__main__":
    main()
