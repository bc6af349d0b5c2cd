"""Run methods on recorded data (``qkf bench CONFIG --data FILE``; docs/recorded_data.md).

The files become the trials of one run (:func:`~.grid.load_recorded`). With truth columns in
every file the run is an ordinary benchmark on those trials (:func:`run_benchmark` with the
recorded data as its source: errors, RMS, NEES, paired ratios), and every method's per-epoch
output is kept for ``estimates.csv`` and the truth-free measures. Without truth only the
methods run, judged by their innovations (:mod:`.quality`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from qkf.core.montecarlo import progress_bar
from qkf.transfer_alignment.benchmark import (
    BenchResult,
    MethodReport,
    parse_methods,
    refuse_tuning_seed,
    run_benchmark,
)
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import CrlbResult
from qkf.transfer_alignment.divergence import Divergence, find_divergences
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.methods import (
    MethodOutput,
    NamedMethod,
    prepare,
    resolve_method,
    resolve_method_settings,
    validate_output,
)
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.recorded.grid import RecordedSet
from qkf.transfer_alignment.recorded.quality import LAGS, BlockQuality, block_quality
from qkf.transfer_alignment.recorded.reader import RecordedDataError
from qkf.transfer_alignment.scenario import ScenarioData

MIN_JUDGED_UPDATES = 4 * LAGS
"""Fewest ADS updates in the settled window for a file to be judged: the whiteness check reads
the autocorrelation up to lag ``LAGS``, and an autocorrelation is read up to lag ``n/4`` at
most (Box and Jenkins), so ``n ≥ 4 · LAGS``. The NIS band fraction of so few epochs is itself
uncertain by ±0.07 (binomial at 0.95), which the flag level (0.90) allows for."""


def refuse_unjudgeable(rec: RecordedSet) -> None:
    """Refuse (:class:`RecordedDataError`) a file with fewer than :data:`MIN_JUDGED_UPDATES`
    ADS updates at ``t ≥ run.settled_s`` (t from the file's first ADS attitude)."""
    cfg = rec.cfg
    settled_s = cfg.run.settled_s
    settled = rec.data.t >= settled_s
    masks = np.broadcast_to(rec.data.has_meas, (rec.data.n_trials, rec.data.n_epochs))
    for info, meas in zip(rec.files, masks, strict=True):
        n = int(np.count_nonzero(meas & settled))
        if n < MIN_JUDGED_UPDATES:
            end = float(rec.data.t[-1])
            raise RecordedDataError(
                f"{info.path}: too short to judge: {n} ADS update(s) at t ≥ run.settled_s = "
                f"{settled_s:g} s (the run spans {end:.6g} s from its first ADS attitude, "
                f"{info.updates:,} updates in all); judging needs at least {MIN_JUDGED_UPDATES} "
                f"there (the whiteness check's {LAGS} lags × 4). Give a longer run, or a shorter "
                "settled window for a short one (--set run.settled_s=…)"
            )


@dataclass
class MethodRun:
    """One method's output on every recorded trial."""

    name: str
    spec: str | None
    out: MethodOutput
    runtime_s: float
    quality: list[list[BlockQuality]] = field(default_factory=list)  # [trial][block]
    divergences: list[Divergence] = field(default_factory=list)  # first epoch per trial


@dataclass
class RecordedResult:
    """Every method on the recorded trials; ``bench`` when the files carry the truth."""

    recorded: RecordedSet
    methods: list[MethodRun]
    bench: BenchResult | None

    @property
    def cfg(self) -> Config:
        return self.recorded.cfg

    @property
    def divergences(self) -> list[Divergence]:
        """Every method's diverged trials (trial: the file's index)."""
        return [d for m in self.methods for d in m.divergences]

    @property
    def file_names(self) -> list[str]:
        """The data file of each trial, as given."""
        return [str(f.path) for f in self.recorded.files]


def _slice(data: ScenarioData, ids: np.ndarray) -> ScenarioData:
    """Trials ``ids`` of recorded ``data`` (a chunk of the benchmark)."""
    from dataclasses import replace

    take = np.asarray(ids)
    return replace(
        data,
        omega_true=data.omega_true[take],
        q_true=data.q_true[take],
        bias=data.bias[take],
        calib=data.calib[take],
        gyro=data.gyro[take],
        ads_q=data.ads_q[take],
        ads_rate=data.ads_rate[take],
        has_meas=data.has_meas if data.has_meas.ndim == 1 else data.has_meas[take],
        trial_ids=data.trial_ids[take],
    )


@dataclass(frozen=True)
class RecordedSource:
    """The benchmark's data source for recorded trials (``DataSource``)."""

    data: ScenarioData

    def __call__(self, cfg: Config, seed: int, ids: np.ndarray) -> ScenarioData:
        return _slice(self.data, ids)


def no_bound(t: np.ndarray) -> CrlbResult:
    """The CRLB of a recorded run: not known (NaN). The bound needs the true rates along the
    recorded trajectory, which the files do not carry; the config's simulated trajectory's
    bound would describe another run."""
    nan = np.broadcast_to(np.nan, (t.size, 15))
    return CrlbResult(t=t, bound=nan, cov=np.broadcast_to(np.nan, (t.size, 15, 15)))


def _named(methods: str | Sequence[str | NamedMethod]) -> list[NamedMethod]:
    if isinstance(methods, str):
        return parse_methods(methods)
    return [m if isinstance(m, NamedMethod) else resolve_method(m) for m in methods]


def run_recorded(
    rec: RecordedSet,
    methods: str | Sequence[str | NamedMethod],
    progress: bool = True,
) -> RecordedResult:
    """Run ``methods`` on the recorded trials of ``rec`` (module doc)."""
    named = _named(methods)
    cfg = resolve_method_settings(rec.cfg, named)
    refuse_tuning_seed(named, cfg.run.seed)
    # every trial in one chunk: the outputs kept are whole (B, N) arrays
    cfg = cfg.model_copy(
        update={"run": cfg.run.model_copy(update={"chunk_trials": rec.data.n_trials})}
    )
    n_cov = covariance_epochs(cfg).size
    kept: dict[str, MethodOutput] = {}
    runtime: dict[str, float] = {}
    if rec.has_truth:

        def keep(name: str, ids: np.ndarray, out: MethodOutput) -> None:
            kept[name] = out

        bench = run_benchmark(
            cfg,
            named,
            trials=rec.data.n_trials,
            seed=cfg.run.seed,
            progress=progress,
            source=RecordedSource(rec.data),
            keep=keep,
            bound=no_bound(rec.data.t),
            weights=state_weights(rec.base_cfg),
        )
        runtime = {m.name: m.runtime_s for m in bench.methods}
    else:
        bench = None
        data = rec.data
        with progress_bar(len(named), "bench: recorded data", progress, "methods") as bar:
            bar.note("preparing methods")
            prepared = [NamedMethod(m.name, prepare(m.method, cfg), m.spec) for m in named]
            report: MethodReport = lambda name, ids, done: bar.note(None if done else name)  # noqa: E731
            for m in prepared:
                report(m.name, data.trial_ids, False)
                t0 = time.perf_counter()
                out = m.method(cfg, data)
                runtime[m.name] = time.perf_counter() - t0
                kept[m.name] = validate_output(out, m.name, data.n_trials, data.n_epochs, n_cov)
                report(m.name, data.trial_ids, True)
                bar(1)
    ids = np.arange(rec.data.n_trials)
    runs = [
        MethodRun(
            m.name,
            m.spec,
            kept[m.name],
            runtime[m.name],
            judge(cfg, rec, kept[m.name]),
            find_divergences(m.name, kept[m.name], rec.data.t, ids),
        )
        for m in named
    ]
    return RecordedResult(rec, runs, bench)


def judge(cfg: Config, rec: RecordedSet, out: MethodOutput) -> list[list[BlockQuality]]:
    """Truth-free quality per trial and innovation block (nothing without the method's NIS)."""
    if out.nis is None:
        return [[] for _ in range(rec.data.n_trials)]
    settled = rec.data.t >= cfg.run.settled_s  # refuse_unjudgeable: never empty on the CLI
    blocks = [("attitude", 0, slice(0, 3))]
    if cfg.filter.matching == "attitude_rate":
        blocks.append(("rate", 1, slice(3, 6)))
    res = []
    for b in range(rec.data.n_trials):
        alive = np.isfinite(out.est[b]).all(axis=-1)
        rows = []
        for name, col, sl in blocks:
            innov = None if out.innov is None else out.innov[b, :, sl]
            rows.append(block_quality(name, out.nis[b, :, col], innov, settled & alive))
        res.append(rows)
    return res
