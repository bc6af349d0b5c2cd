"""Monte Carlo benchmark of filters on a scenario: config → scenario → filter → metrics → report.

Trials are simulated in chunks (``run.chunk_trials``); every method sees the same simulated
data (paired comparison), and trial ``i`` is the same whatever the chunking. Results are held
in memory and written only when the run has finished (atomically, see ``qkf.core.io``).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import CrlbResult, crlb
from qkf.transfer_alignment.methods import METHODS, MethodOutput, resolve_method
from qkf.transfer_alignment.methods.base import action_values, decision_period
from qkf.transfer_alignment.metrics import ErrorAccumulator, state_errors, summarize
from qkf.transfer_alignment.scenario import n_epochs, simulate
from qkf.transfer_alignment.states import DISPLAY_UNIT


@dataclass
class MethodResult:
    name: str
    rms: np.ndarray  # (N, 15) SI, RMS over trials per epoch
    trials: int
    diverged: int
    runtime_s: float
    summary: dict[str, float] = field(default_factory=dict)  # display units
    kappa: np.ndarray | None = None  # (trials, T) κ in use at the decision times
    notes: dict[str, str] = field(default_factory=dict)


@dataclass
class BenchResult:
    config: Config
    seed: int
    trials: int
    t: np.ndarray
    methods: list[MethodResult]
    bound: CrlbResult
    kappa_t: np.ndarray  # (T,) s, the times at which κ traces are sampled


def kappa_trace(cfg: Config, out: MethodOutput, n: int, period: int) -> np.ndarray | None:
    """κ in use per trial at every ``period``-th epoch (B, T), for the plots and kappa.csv.

    Per-term κ (Sage–Husa) is summarised by its geometric mean, a bank (MMAE) by the
    probability-weighted geometric mean; fixed-κ methods return None.
    """
    idx = np.arange(0, n, period)
    if "kappa_index" in out.extras:
        return action_values(cfg)[out.extras["kappa_index"]]
    if "kappa" in out.extras:
        return np.exp(np.mean(np.log(out.extras["kappa"][:, idx]), axis=-1))
    if "weights" in out.extras:
        return np.exp(out.extras["weights"][:, idx] @ np.log(action_values(cfg)))
    return None


def _is_policy(name: str) -> bool:
    return name.startswith("policy:") and Path(name[len("policy:") :]).is_file()


def parse_methods(spec: str | list[str]) -> list[str]:
    """Split ``"kf,qkf"`` (or ``"all"``) into method names; ``ValueError`` for unknown ones."""
    if spec == "all":
        return list(METHODS)
    names = [m.strip() for m in (spec.split(",") if isinstance(spec, str) else spec) if m.strip()]
    if not names:
        raise ValueError("no method given")
    unknown = [m for m in names if m not in METHODS and not _is_policy(m)]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)}; known: {', '.join(METHODS)}")
    return names


@dataclass
class ChunkResult:
    """What one chunk of trials contributes, per method (summed in chunk order afterwards)."""

    sum_sq: dict[str, np.ndarray]  # (N, 15) sums over the chunk's trials of squared errors
    count: int
    diverged: dict[str, int]
    runtime_s: dict[str, float]
    kappa: dict[str, np.ndarray | None]
    notes: dict[str, dict[str, str]]


def run_chunk(cfg: Config, methods: list[str], seed: int, ids: np.ndarray) -> ChunkResult:
    """Simulate trials ``ids`` and run every method on them (the unit of work of a backend)."""
    n = n_epochs(cfg.scenario)
    period = decision_period(cfg)
    data = simulate(cfg, seed, ids)
    res = ChunkResult({}, ids.size, {}, {}, {}, {})
    for m in methods:
        t0 = time.perf_counter()
        out = resolve_method(m)(cfg, data)
        res.runtime_s[m] = time.perf_counter() - t0
        err = state_errors(out.est, data.q_true, data.bias, data.calib)
        res.sum_sq[m] = np.sum(err * err, axis=0)
        res.diverged[m] = int(np.count_nonzero(out.diverged))
        res.kappa[m] = kappa_trace(cfg, out, n, period)
        res.notes[m] = dict(out.notes)
    return res


def _single_thread_worker() -> None:
    # each process is one worker: numba's own threads would oversubscribe the cores
    import numba

    numba.set_num_threads(1)


def _chunk_results(
    cfg: Config, methods: list[str], seed: int, chunks: list[np.ndarray], backend: str, workers: int
) -> Iterator[ChunkResult]:
    """Chunk results in chunk order, whatever order the backend finishes them in."""
    if backend == "local" and workers <= 1:
        for ids in chunks:
            yield run_chunk(cfg, methods, seed, ids)
    elif backend == "local":
        # spawn, not fork: the parent's numba threads (OpenMP) do not survive a fork
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            workers, mp_context=ctx, initializer=_single_thread_worker
        ) as pool:
            futures = [pool.submit(run_chunk, cfg, methods, seed, ids) for ids in chunks]
            for fut in futures:
                yield fut.result()
    elif backend == "ray":
        yield from _ray_chunk_results(cfg, methods, seed, chunks)
    else:
        raise ValueError(f"unknown backend {backend!r}: local or ray")


def _ray_chunk_results(
    cfg: Config, methods: list[str], seed: int, chunks: list[np.ndarray]
) -> Iterator[ChunkResult]:
    try:
        import ray
    except ImportError:  # pragma: no cover - depends on the extra
        raise RuntimeError("the ray backend needs the extra: pip install -e '.[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        address = cfg.run.ray_address or os.environ.get("RAY_ADDRESS")
        # no address: a local cluster on this machine
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(run_chunk)
        refs = [task.remote(cfg, methods, seed, ids) for ids in chunks]
        for ref in refs:
            yield ray.get(ref)
    finally:
        if started_here:
            ray.shutdown()


def run_benchmark(
    cfg: Config,
    methods: list[str],
    trials: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    backend: str = "local",
    workers: int | None = None,
) -> BenchResult:
    """Run every method on the same ``trials`` Monte Carlo trials of ``cfg``'s scenario.

    ``backend``: ``local`` (in this process when ``workers`` is 1, else a process pool) or
    ``ray`` (one Ray task per chunk; ``run.ray_address`` or ``RAY_ADDRESS``, else a local
    cluster). Chunks are combined in chunk order, so every backend gives the same numbers.
    """
    trials = cfg.run.trials if trials is None else trials
    seed = cfg.run.seed if seed is None else seed
    workers = cfg.run.workers if workers is None else workers
    if trials < 1:
        raise ValueError("trials must be at least 1")
    methods = parse_methods(methods)
    n = n_epochs(cfg.scenario)
    period = decision_period(cfg)
    acc = {m: ErrorAccumulator(n) for m in methods}
    runtime = dict.fromkeys(methods, 0.0)
    kappas: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    notes: dict[str, dict[str, str]] = {m: {} for m in methods}
    chunk = cfg.run.chunk_trials
    chunks = [np.arange(lo, min(trials, lo + chunk)) for lo in range(0, trials, chunk)]
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        disable=not progress,
        transient=False,
    ) as bar:
        task = bar.add_task(f"{', '.join(methods)} ({backend})", total=trials)
        for res in _chunk_results(cfg, methods, seed, chunks, backend, workers):
            for m in methods:
                acc[m].add_sums(res.sum_sq[m], res.count, res.diverged[m])
                runtime[m] += res.runtime_s[m]
                trace = res.kappa[m]
                if trace is not None:
                    kappas[m].append(trace)
                notes[m].update(res.notes[m])
            bar.advance(task, res.count)
    results = []
    for m in methods:
        rms = acc[m].rms()
        results.append(
            MethodResult(
                name=m,
                rms=rms,
                trials=acc[m].count,
                diverged=acc[m].diverged,
                runtime_s=runtime[m],
                summary=summarize(rms / DISPLAY_UNIT),
                kappa=np.concatenate(kappas[m]) if kappas[m] else None,
                notes=notes[m],
            )
        )
    return BenchResult(
        config=cfg,
        seed=seed,
        trials=trials,
        t=np.arange(n) * cfg.scenario.dt_s,
        methods=results,
        bound=crlb(cfg),
        kappa_t=np.arange(0, n, period) * cfg.scenario.dt_s,
    )
