"""The redundant-gyro environments against the filterpy loop they used to run (docs/performance.md,
"Issue 35: the gyro environments").

Run: ``.venv/bin/python benchmarks/gyro_env_speed.py [--seconds 6] [--envs 64]``.

Reference, timed in the same run: what one step of ``qkf/RedundantGyroCalibration-v1`` cost
before it was compiled — two filterpy UKFs (:class:`qkf.redundant_gyros.ukf.CalibrationUKF`, the
agent's and the κ = 1 copy of the likelihood gain) stepped over one decision period (100
epochs), one episode at a time, with an episode drawn (``EpisodeSampler.draw``) every
``episode_steps`` steps. Measured:

* the single environment, ``gym.make(id)``, v1 (with the κ = 1 copy), v2 (without) and v4
  (with the VB noise scale, whose statistics keep each epoch's covariance): env-steps/s and
  the ratio to the reference (goals ≥ 3,000 env-steps/s and ≥ 100 ×);
* the batched Gymnasium vector environment, ``gym.make_vec(id, num_envs=N)``, v1, v2 and v4:
  env-steps/s summed over its N episodes (goal ≥ 30,000 with 64).

Random discrete actions; resets (new episodes) are part of the time. Each figure is the best of
three windows sharing ``--seconds`` (interference only slows a window down).
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

import envs  # noqa: F401  (registers the ids)
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.ukf import CalibrationUKF

warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)


def best_rate(step: Callable[[], int], seconds: float, windows: int = 3) -> float:
    """Units per second of ``step`` (it returns how many units it did): best of ``windows``."""
    step()
    best = 0.0
    for _ in range(windows):
        units, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds / windows:
            units += step()
        best = max(best, units / (time.perf_counter() - t0))
    return best


def filterpy_reference(seconds: float) -> float:
    """Env-steps/s of the filterpy loop of the old v1 environment (module docstring)."""
    sampler = EpisodeSampler(load_config("five_gyros_onset_drift"))
    period = 100
    steps = -(-sampler.n_epochs // period)
    kappas = np.logspace(-2, 2, 11)
    rng = np.random.default_rng(0)
    state: dict[str, Any] = {"k": 0, "ep": sampler.draw(0)}
    agent = CalibrationUKF(sampler.setup, float(sampler.dt[0]))
    copy = CalibrationUKF(sampler.setup, float(sampler.dt[0]))

    def step() -> int:
        if state["k"] >= steps:
            state["k"], state["ep"] = 0, sampler.draw(int(rng.integers(2**62)))
            agent.load(sampler.setup.x0, np.diag(sampler.setup.p0_sd**2))
        ep, k0 = state["ep"], state["k"] * period
        kappa = float(kappas[rng.integers(kappas.size)])
        copy.load(agent.x, agent.P)
        for k in range(k0, min(k0 + period, sampler.n_epochs)):
            z, r, dt = float(ep.z[k]), ep.rate[k], float(ep.dt[k])
            agent.step(z, r, dt, kappa)
            copy.step(z, r, dt, 1.0)
        state["k"] += 1
        return 1

    return best_rate(step, seconds)


def single_rate(env_id: str, seconds: float) -> float:
    env = gym.make(env_id)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step() -> int:
        _, _, term, trunc, _ = env.step(int(rng.integers(11)))
        if term or trunc:
            env.reset()
        return 1

    return best_rate(step, seconds)


def batched_rate(env_id: str, n: int, seconds: float) -> float:
    env = gym.make_vec(env_id, num_envs=n)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step() -> int:
        env.step(rng.integers(0, 11, n))
        return n

    return best_rate(step, seconds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=6.0, help="per measurement")
    ap.add_argument("--envs", type=int, default=64, help="episodes of the batched environment")
    args = ap.parse_args()
    ref = filterpy_reference(args.seconds)
    print(f"reference: filterpy v1 loop (two UKFs per epoch)   {ref:10.1f} env-steps/s")
    for v in ("v1", "v2", "v4"):
        env_id = f"qkf/RedundantGyroCalibration-{v}"
        single = single_rate(env_id, args.seconds)
        print(f"{env_id} single          {single:10.0f} env-steps/s  {single / ref:7.0f} × ref")
    for v in ("v1", "v2", "v4"):
        env_id = f"qkf/RedundantGyroCalibration-{v}"
        batched = batched_rate(env_id, args.envs, args.seconds)
        rate = f"{batched:10.0f} env-steps/s  {batched / ref:7.0f} × ref"
        print(f"{env_id} batched × {args.envs}  {rate}")


if __name__ == "__main__":
    main()
