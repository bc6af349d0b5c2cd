"""The single environment against a plain filterpy loop, and under load (docs/performance.md).

Run: ``.venv/bin/python benchmarks/single_env_speed.py [--seconds 3] [--subproc 4]``.

For every transfer-alignment id (``gym.make(id)``, one episode at a time, B = 1) it measures
env-steps per second and the filter-epochs per second they imply, counting every filter a step
runs: the agent's filter (one decision period), the κ = 1 shadow where the reward or the
observation needs the likelihood gain, and the reference filter of the ``*_gain`` rewards (a
whole episode at each reset, spread over the episode's steps). The reference is a plain
filterpy loop of the same 15-state filter (predict/update with matrices evaluated beforehand,
``benchmarks/filter_speed.py``), timed in the same run, best of six runs before and after the
environments (each environment: best of three windows): ``single_env_vs_filterpy`` is the ratio
of filter-epochs per second (goal ≥ 2).

``--subproc N``: Stable-Baselines3's ``SubprocVecEnv`` with N single environments against one
environment in this process, ``subproc_vs_single`` (goal ≥ 1.5 with 4 environments on 2 cores:
no collapse from thread oversubscription).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import envs

sys.path.insert(0, str(Path(__file__).resolve().parent))
from filter_speed import filterpy_rate

from qkf.transfer_alignment.config import load_config


def steps_per_s(step, seconds: float, windows: int = 3) -> float:  # type: ignore[no-untyped-def]
    """Calls per second of ``step``: the best of ``windows`` windows sharing ``seconds`` (on a
    shared machine, interference only slows a window down; the reference is timed the same
    way, best of its repeats)."""
    step()
    best = 0.0
    for _ in range(windows):
        calls, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds / windows:
            step()
            calls += 1
        best = max(best, calls / (time.perf_counter() - t0))
    return best


def single_rate(env_id: str, seconds: float) -> tuple[float, float]:
    """Env-steps/s of one environment and the filter-epochs one step runs on average."""
    env = gym.make(env_id)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    n_act = int(env.action_space.n)  # type: ignore[attr-defined]

    def step() -> None:
        _, _, term, trunc, _ = env.step(int(rng.integers(n_act)))
        if term or trunc:
            env.reset()

    rate = steps_per_s(step, seconds)
    core = env.unwrapped._driver.core  # type: ignore[attr-defined]
    per_step = core.period * (1 + (core.nominal is not None))
    if core.needs_reference:  # one whole-episode run per reset
        per_step += core.n_epochs / math.ceil(core.n_epochs / core.period)
    return rate, per_step


def subproc_ratio(env_id: str, n: int, seconds: float) -> tuple[float, float]:
    """Env-steps/s of SubprocVecEnv(n) and of one environment in this process."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = make_vec_env(env_id, n_envs=n, seed=0, vec_env_cls=SubprocVecEnv)
    vec.reset()
    rng = np.random.default_rng(1)
    rate = steps_per_s(lambda: vec.step(rng.integers(0, 11, n)), seconds) * n
    vec.close()
    single, _ = single_rate(env_id, seconds)
    return rate, single


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--ids", default="", help="comma-separated ids (default: every TA id)")
    ap.add_argument("--subproc", type=int, default=4, help="0 skips the SubprocVecEnv check")
    args = ap.parse_args()
    ids = [i for i in args.ids.split(",") if i] or [
        env_id
        for env_id in envs.ENVIRONMENTS.names()
        if envs.ENVIRONMENTS[env_id].problem == "transfer_alignment"
    ]
    cfg = load_config("paper")
    ref = filterpy_rate(cfg, 2, repeats=3)
    rows = []
    for env_id in ids:
        rate, per_step = single_rate(env_id, args.seconds)
        rows.append((env_id, rate, per_step))
    ref = max(ref, filterpy_rate(cfg, 2, repeats=3))  # best of before and after the envs
    print(f"filterpy loop: {ref:,.0f} filter-epochs/s (best of 6 runs); cpus {os.cpu_count()}")
    for env_id, rate, per_step in rows:
        print(
            f"{env_id:32s} {rate:8,.0f} env-steps/s  {per_step:5.1f} filter-epochs/step  "
            f"{rate * per_step:10,.0f} filter-epochs/s  "
            f"single_env_vs_filterpy: {rate * per_step / ref:.2f}"
        )
    if args.subproc:
        env_id = ids[-1]
        vec, single = subproc_ratio(env_id, args.subproc, args.seconds)
        print(
            f"SubprocVecEnv({args.subproc}) {env_id}: {vec:,.0f} env-steps/s, one env "
            f"{single:,.0f}: subproc_vs_single: {vec / single:.2f}"
        )


if __name__ == "__main__":
    main()
