"""Monte Carlo benchmark of filters on a scenario: config → scenario → filter → metrics → report.

Trials are simulated in chunks (``run.chunk_trials``); every method sees the same simulated
data (paired comparison), and trial ``i`` is the same whatever the chunking. Results are held
in memory and written only when the run has finished (atomically, see ``qkf.io``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from qkf.config import Config
from qkf.crlb import CrlbResult, crlb
from qkf.filters import FilterParams, TransferAlignmentKF
from qkf.metrics import ErrorAccumulator, state_errors, summarize
from qkf.scenario import ScenarioData, n_epochs, simulate
from qkf.states import DISPLAY_UNIT

MethodFn = Callable[[Config, ScenarioData], tuple[np.ndarray, np.ndarray]]
"""A method filters the trials of ``ScenarioData``; returns ``(est (B, N, 16), diverged (B,))``."""


def run_fixed_kappa(cfg: Config, data: ScenarioData, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """The transfer-alignment KF with a constant process-noise factor ``κ``."""
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), data.n_trials)
    kf.initialize(data.ads_q[:, 0])
    rec = kf.step_data(data, 0, data.n_epochs, kappa=kappa)
    return rec.est, kf.diverged.copy()


def _kf(cfg: Config, data: ScenarioData) -> tuple[np.ndarray, np.ndarray]:
    return run_fixed_kappa(cfg, data, cfg.run.kappa)


METHODS: dict[str, MethodFn] = {"kf": _kf}
"""Methods available to ``qkf bench --methods``."""


@dataclass
class MethodResult:
    name: str
    rms: np.ndarray  # (N, 15) SI, RMS over trials per epoch
    trials: int
    diverged: int
    runtime_s: float
    summary: dict[str, float] = field(default_factory=dict)  # display units


@dataclass
class BenchResult:
    config: Config
    seed: int
    trials: int
    t: np.ndarray
    methods: list[MethodResult]
    bound: CrlbResult


def parse_methods(spec: str | list[str]) -> list[str]:
    """Split ``"kf,qkf"`` into known method names; raises ``ValueError`` for unknown ones."""
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
    acc = {m: ErrorAccumulator(n) for m in methods}
    runtime = dict.fromkeys(methods, 0.0)
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
                est, diverged = METHODS[m](cfg, data)
                runtime[m] += time.perf_counter() - t0
                acc[m].add(state_errors(est, data.q_true, data.bias, data.calib), diverged)
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
            )
        )
    return BenchResult(
        config=cfg,
        seed=seed,
        trials=trials,
        t=np.arange(n) * cfg.scenario.dt_s,
        methods=results,
        bound=crlb(cfg),
    )
