"""Monte Carlo bench of the toy filter on the core runner (:mod:`qkf.core.montecarlo`).

:func:`run_chunk` is the picklable unit of work (a module-level function and plain data, so
process-pool and Ray workers import it by name); its sums are added in chunk order, so every
backend gives the same numbers bit for bit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from qkf.core.montecarlo import chunk_ids, progress_bar, run_chunks
from qkf.core.stats import average_nees_band
from tests.example_problem.toy_estimation.config import ToyConfig
from tests.example_problem.toy_estimation.estimator import kalman_filter
from tests.example_problem.toy_estimation.scenario import n_epochs, simulate


@dataclass(frozen=True)
class ChunkResult:
    sum_sq: np.ndarray  # (N,) Σ over the chunk's trials of the squared error, u²
    nees_sum: np.ndarray  # (N,) Σ over the chunk's trials of e² / P
    trials: int


def run_chunk(cfg: ToyConfig, seed: int, ids: np.ndarray) -> ChunkResult:
    """Simulate trials ``ids`` and filter them (the unit of work of a backend)."""
    data = simulate(cfg, seed, ids)
    est, var = kalman_filter(cfg, data.z)
    sq = (est - data.x) ** 2
    return ChunkResult(sq.sum(axis=0), (sq / var).sum(axis=0), len(ids))


@dataclass(frozen=True)
class BenchResult:
    cfg: ToyConfig
    trials: int
    seed: int
    t: np.ndarray  # (N,) s
    rms: np.ndarray  # (N,) RMS error over trials, u
    sd: np.ndarray  # (N,) the filter's own 1-σ, u
    nees: np.ndarray  # (N,) NEES averaged over trials (1 for a consistent filter)
    band: tuple[float, float]  # two-sided χ²(trials)/trials band of probability bench.level
    backend: str
    workers: int
    runtime_s: float

    @property
    def in_band(self) -> float:
        """Fraction of the epochs whose trial-averaged NEES lies inside the band."""
        return float(np.mean((self.nees >= self.band[0]) & (self.nees <= self.band[1])))


def run_bench(
    cfg: ToyConfig,
    trials: int | None = None,
    seed: int | None = None,
    *,
    backend: str = "local",
    workers: int = 1,
    progress: bool = False,
) -> BenchResult:
    """``trials`` Monte Carlo trials (default ``bench.trials``) on ``backend``."""
    tic = time.perf_counter()
    trials = cfg.bench.trials if trials is None else trials
    seed = cfg.bench.seed if seed is None else seed
    n = n_epochs(cfg)
    sum_sq, nees_sum = np.zeros(n), np.zeros(n)
    task = partial(run_chunk, cfg, seed)
    with progress_bar(trials, "toy bench", progress) as bar:
        for res in run_chunks(task, chunk_ids(trials, cfg.bench.chunk_trials), backend, workers):
            sum_sq += res.sum_sq  # in chunk order: the same sums on every backend
            nees_sum += res.nees_sum
            bar(res.trials)
    _, var = kalman_filter(cfg, np.zeros((0, n)))  # P needs no data
    lo, hi = average_nees_band(1, np.array(trials), cfg.bench.level)
    return BenchResult(
        cfg=cfg,
        trials=trials,
        seed=seed,
        t=np.arange(n) * cfg.walk.dt_s,
        rms=np.sqrt(sum_sq / trials),
        sd=np.sqrt(var),
        nees=nees_sum / trials,
        band=(float(lo), float(hi)),
        backend=backend,
        workers=workers,
        runtime_s=time.perf_counter() - tic,
    )
