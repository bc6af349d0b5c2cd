"""Monte Carlo benchmark of filters on a scenario: config → scenario → filter → metrics → report.

Trials are simulated in chunks (``run.chunk_trials``); every method sees the same simulated
data (paired comparison), and trial ``i`` is the same whatever the chunking. Results are held
in memory and written only when the run has finished (atomically, see ``qkf.io``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from qkf.config import Config
from qkf.crlb import CrlbResult, crlb
from qkf.methods import METHODS, MethodOutput
from qkf.methods.base import action_values
from qkf.metrics import ErrorAccumulator, state_errors, summarize
from qkf.scenario import n_epochs, simulate
from qkf.states import DISPLAY_UNIT


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


def parse_methods(spec: str | list[str]) -> list[str]:
    """Split ``"kf,qkf"`` (or ``"all"``) into method names; ``ValueError`` for unknown ones."""
    if spec == "all":
        return list(METHODS)
    names = [m.strip() for m in (spec.split(",") if isinstance(spec, str) else spec) if m.strip()]
    if not names:
        raise ValueError("no method given")
    unknown = [m for m in names if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)}; known: {', '.join(METHODS)}")
    return names


def run_benchmark(
    cfg: Config,
    methods: list[str],
    trials: int | None = None,
    seed: int | None = None,
    progress: bool = True,
) -> BenchResult:
    """Run every method on the same ``trials`` Monte Carlo trials of ``cfg``'s scenario."""
    trials = cfg.run.trials if trials is None else trials
    seed = cfg.run.seed if seed is None else seed
    if trials < 1:
        raise ValueError("trials must be at least 1")
    methods = parse_methods(methods)
    n = n_epochs(cfg.scenario)
    period = max(1, round(cfg.adaptive.qkf.period_s / cfg.scenario.dt_s))
    acc = {m: ErrorAccumulator(n) for m in methods}
    runtime = dict.fromkeys(methods, 0.0)
    kappas: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    notes: dict[str, dict[str, str]] = {m: {} for m in methods}
    chunk = cfg.run.chunk_trials
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        disable=not progress,
        transient=False,
    ) as bar:
        tasks = {m: bar.add_task(m, total=trials) for m in methods}
        for lo in range(0, trials, chunk):
            ids = np.arange(lo, min(trials, lo + chunk))
            data = simulate(cfg, seed, ids)
            for m in methods:
                t0 = time.perf_counter()
                out = METHODS[m](cfg, data)
                runtime[m] += time.perf_counter() - t0
                acc[m].add(state_errors(out.est, data.q_true, data.bias, data.calib), out.diverged)
                trace = kappa_trace(cfg, out, n, period)
                if trace is not None:
                    kappas[m].append(trace)
                notes[m].update(out.notes)
                bar.advance(tasks[m], ids.size)
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
