"""Simulation of the toy problem, vectorised over trials, each trial seeded on its own."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tests.example_problem.toy_estimation.config import ToyConfig


@dataclass(frozen=True)
class WalkData:
    t: np.ndarray  # (N,) s
    x: np.ndarray  # (B, N) true value, u
    z: np.ndarray  # (B, N) readings, u


def n_epochs(cfg: ToyConfig) -> int:
    return round(cfg.walk.duration_s / cfg.walk.dt_s)


def simulate(cfg: ToyConfig, seed: int, ids: np.ndarray) -> WalkData:
    """Trials ``ids``: trial k of seed s draws from ``SeedSequence([s, k])`` alone, so it is the
    same in any chunk, batch or backend."""
    w, n = cfg.walk, n_epochs(cfg)
    x = np.empty((len(ids), n))
    z = np.empty((len(ids), n))
    for row, k in enumerate(ids):
        rng = np.random.default_rng([seed, int(k)])
        start = w.prior_sd_u * rng.standard_normal()
        steps = w.walk_u_per_sqrt_s * np.sqrt(w.dt_s) * rng.standard_normal(n - 1)
        x[row] = start + np.concatenate(([0.0], np.cumsum(steps)))
        z[row] = x[row] + w.noise_u * rng.standard_normal(n)
    return WalkData(np.arange(n) * w.dt_s, x, z)
