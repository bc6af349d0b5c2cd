"""``qkf gyros bench``: detection and isolation of three-cross against the GLT over fault kinds
and sizes, and the UKF's calibration accuracy over Monte Carlo trials (docs/redundant_gyros.md,
"Bench").

Fault sizes are in σ units, σ the gyro's white-noise sd, and turn into a fault per kind so that
the fault's effect on the reading is about ``size · σ`` (:func:`bench_fault`). Trial k carries
the fault on gyro ``k mod n`` and draws its noise from ``(seed, k)``, so every kind and size
sees the same noise (common random numbers). Three detectors are scored on the same readings:
``threecross``, ``glt`` (per epoch) and ``glt_window`` (the configured window).

The trials run on the chunked runner of :mod:`qkf.core.montecarlo`, as the transfer-alignment
bench does: :func:`run_chunk` is the picklable unit of work, :class:`BenchPlan` numbers the work
items and cuts them into chunks, and the chunk results are combined in chunk order, so the
``local`` backend (in this process or ``workers`` processes) and ``ray`` give the same numbers
bit for bit. A trial's counts depend on its seed, trial number, fault group and the config
only, never on the chunk it runs in.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from qkf.core.montecarlo import chunk_ids, progress_bar, run_chunks
from qkf.core.stats import nees, resample_counts
from qkf.redundant_gyros.config import BenchConfig, Fault, GyrosConfig
from qkf.redundant_gyros.fdi import Detectors
from qkf.redundant_gyros.geometry import GyroUnit, build_unit
from qkf.redundant_gyros.metrics import (
    Estimate,
    TrialCounts,
    convergence_step,
    convergence_tolerance,
    count_trials,
    nees_band,
    summarize_counts,
)
from qkf.redundant_gyros.pipeline import Target, fault_target, setup_for
from qkf.redundant_gyros.scenario import body_rate, epochs, first_epoch, simulate
from qkf.redundant_gyros.ukf import DISPLAY_SCALE, UkfSetup, calibrate

METHODS = ("threecross", "glt", "glt_window")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x)))


def bench_fault(
    kind: str, size_sigma: float, unit: GyroUnit, gyro: int, rate: np.ndarray, bench: BenchConfig
) -> Fault:
    """A fault of ``gyro`` whose effect on its reading is about ``size_sigma · σ``: a bias step
    of that size; a ramp reaching it after ``ramp_s``; a scale step ``Δλ = size σ / rms(w·ω)``;
    a misalignment step ``Δδ_u = Δδ_v = size σ / rms((u + v)·ω)``; a stuck output offset by
    it; a noise increase by the factor ``size``."""
    sigma = float(unit.noise[gyro])
    effect = size_sigma * sigma
    gid = unit.ids[gyro]
    t0 = bench.fault_time_s
    if kind == "bias_step":
        return Fault(gyro=gid, t_s=t0, kind="bias_step", size=effect)
    if kind == "bias_ramp":
        return Fault(gyro=gid, t_s=t0, kind="bias_ramp", size=effect / bench.ramp_s)
    if kind == "scale_step":
        return Fault(gyro=gid, t_s=t0, kind="scale_step", size=effect / _rms(rate @ unit.w[gyro]))
    if kind == "misalignment_step":
        d = np.degrees(effect / _rms(rate @ (unit.u[gyro] + unit.v[gyro])))
        return Fault(gyro=gid, t_s=t0, kind="misalignment_step", size=(float(d), float(d)))
    if kind == "stuck":
        return Fault(gyro=gid, t_s=t0, kind="stuck", size=effect)
    if kind == "noise_increase":
        return Fault(gyro=gid, t_s=t0, kind="noise_increase", size=float(size_sigma))
    raise ValueError(f"unknown fault kind {kind!r}")


@dataclass(frozen=True)
class BenchRow:
    method: str
    kind: str
    size_sigma: float
    trials: int
    metrics: dict[str, Estimate]
    never_detected: int


@dataclass(frozen=True)
class UkfAccuracy:
    """UKF errors over Monte Carlo trials, per step after the start (display units)."""

    gyro: str
    start_s: float
    t: np.ndarray  # (K,) s since the start
    rms: np.ndarray  # (K, 4) RMS error over trials
    sd: np.ndarray  # (K, 4) RMS of the filter's own sd
    nees: np.ndarray  # (K,) mean NEES over trials
    band: tuple[float, float]
    trials: int
    diverged: int
    converged_step: list[int | None]  # per trial
    seconds_per_step: float


@dataclass(frozen=True)
class BenchResult:
    cfg: GyrosConfig
    trials: int
    seed: int
    rows: list[BenchRow]
    ukf: UkfAccuracy | None
    ukf_note: str
    separability: list[str]
    fdi_epochs: int
    fdi_seconds: float  # time spent in the detectors, summed over chunks (on any backend)
    runtime_s: float  # wall time of the whole run
    backend: str = "local"
    workers: int = 1


@dataclass(frozen=True)
class UkfWork:
    """The UKF accuracy run: ``trials`` trials of the config's own scenario, calibrating
    ``target.gyro`` from ``target.start`` with ``setup`` (oracle isolation: the filter is judged
    alone, from the configured fault on)."""

    trials: int
    target: Target
    setup: UkfSetup


@dataclass(frozen=True)
class BenchPlan:
    """The work of one bench run, and how its chunks number it.

    Work item ids: FDI trial ``k`` of fault group ``g`` (``groups[g]``) is ``g · trials + k``;
    UKF trial ``k`` is ``len(groups) · trials + k`` (:attr:`ukf_offset`). A chunk holds the
    trials of one group and one faulty gyro (they share one simulated fault), or UKF trials
    only.
    """

    groups: tuple[tuple[str, float], ...]  # (fault kind, size in σ), kinds outer, sizes inner
    trials: int  # FDI trials per group
    n_gyros: int
    chunk_trials: int  # at most this many trials are simulated at once (memory)
    ukf: UkfWork | None = None

    @property
    def ukf_offset(self) -> int:
        """The id of UKF trial 0."""
        return len(self.groups) * self.trials

    def chunks(self) -> list[np.ndarray]:
        """Every work item once, in the order the results are combined in.

        The UKF trials come first, one per chunk: each is a whole filter run, about 1.6 s on
        the paper's scenarios (5,400 steps of about 300 µs), more than the FDI of a whole chunk,
        so a pool starts them at once instead of leaving one worker with them at the end. Then,
        per group and faulty gyro in index order, that gyro's trials (``k ≡ gyro mod n``) in
        chunks of at most ``chunk_trials``: the order in which the per-trial counts are
        concatenated, which the bootstrap's resampled trial indices refer to.
        """
        out: list[np.ndarray] = []
        if self.ukf is not None:
            out += [self.ukf_offset + ids for ids in chunk_ids(self.ukf.trials, 1)]
        for g in range(len(self.groups)):
            for gyro in range(self.n_gyros):
                ids = np.arange(gyro, self.trials, self.n_gyros)
                if ids.size == 0:  # fewer trials than gyros: this gyro carries none
                    continue
                out += [g * self.trials + ids[c] for c in chunk_ids(ids.size, self.chunk_trials)]
        return out


@dataclass(frozen=True)
class FdiChunk:
    """What one chunk of FDI trials contributes: per-trial counts of every detector."""

    group: int  # index into BenchPlan.groups
    counts: dict[str, TrialCounts]  # per detector, the chunk's trials in order
    epochs: int  # trial-epochs scored
    seconds: float  # time spent in the detectors on them

    @property
    def trials(self) -> int:
        return int(self.counts[METHODS[0]].pre_epochs.size)


@dataclass(frozen=True)
class UkfChunk:
    """What one chunk of UKF trials contributes (internal units, trials in order)."""

    err: np.ndarray  # (B, K, 4) estimate − truth
    cov: np.ndarray  # (B, K, 4, 4) the filter's covariance
    diverged: np.ndarray  # (B,) bool
    converged_step: list[int | None]  # per trial
    seconds: float  # time spent in the filter


ChunkResult = FdiChunk | UkfChunk


def _windows(det: Detectors) -> dict[str, int]:
    return {
        "threecross": det.threecross.window,
        "glt": 1,
        "glt_window": det.glt.window,
    }


def _score_chunk(
    det: Detectors, meas: np.ndarray, faulty: int, k0: int, dt: float
) -> dict[str, TrialCounts]:
    y = det.unit.compensate(meas)
    _, iso_tc = det.threecross.isolate(y)
    iso = {
        "threecross": iso_tc,
        "glt": det.glt_epoch.test(y).isolated,
        "glt_window": det.glt.test(y).isolated,
    }
    win = _windows(det)
    return {m: count_trials(iso[m], faulty, k0, win[m], dt) for m in METHODS}


def run_chunk(
    cfg: GyrosConfig, det: Detectors, plan: BenchPlan, seed: int, ids: np.ndarray
) -> ChunkResult:
    """Simulate and score the work items ``ids`` of ``plan`` (the unit of work of a backend).

    ``det``: the detectors, built once by the caller (the three-cross null probabilities take a
    Monte Carlo run of about 0.3 s) and shipped with the task. Any subset of one chunk's ids
    gives the same per-trial results as the whole chunk (trial ``k`` of seed ``s`` draws its
    noise from ``(s, k)`` alone). ``ValueError`` for ids that do not form a chunk of ``plan``.
    """
    ids = np.asarray(ids, dtype=np.int64)
    if ids.size == 0:
        raise ValueError("an empty chunk")
    if ids[0] >= plan.ukf_offset:
        if plan.ukf is None or not np.all(ids >= plan.ukf_offset):
            raise ValueError("a chunk of UKF trials holds UKF trials only, of a plan with some")
        return _ukf_chunk(cfg, det.unit, plan.ukf, seed, ids - plan.ukf_offset)
    group, trial_ids = np.divmod(ids, plan.trials)
    gyro = int(trial_ids[0] % plan.n_gyros)
    if np.any(group != group[0]) or np.any(trial_ids % plan.n_gyros != gyro):
        raise ValueError("a chunk of FDI trials holds one fault group and one faulty gyro")
    b = cfg.bench
    kind, size = plan.groups[int(group[0])]
    dt = cfg.scenario.dt_s
    t = epochs(b.duration_s, dt)
    k0 = first_epoch(t, b.fault_time_s)
    fault = bench_fault(kind, size, det.unit, gyro, body_rate(cfg.scenario.body_rate, t), b)
    data = simulate(det.unit, cfg.scenario.body_rate, [fault], t, seed, trial_ids)
    tic = time.perf_counter()
    scored = _score_chunk(det, data.meas, gyro, k0, dt)
    seconds = time.perf_counter() - tic
    return FdiChunk(int(group[0]), scored, data.meas.shape[0] * t.size, seconds)


def _ukf_chunk(
    cfg: GyrosConfig, unit: GyroUnit, work: UkfWork, seed: int, trial_ids: np.ndarray
) -> UkfChunk:
    """The UKF on trials ``trial_ids`` of the config's own scenario, from the target's start."""
    sc = cfg.scenario
    t = epochs(sc.duration_s, sc.dt_s)
    target, setup = work.target, work.setup
    data = simulate(unit, sc.body_rate, sc.faults, t, seed, trial_ids)
    assert data.coeffs is not None  # a simulation always knows its truth
    truth = data.coeffs[target.start :, target.gyro]
    b, k = trial_ids.size, truth.shape[0]
    err = np.full((b, k, 4), np.nan)
    cov = np.full((b, k, 4, 4), np.nan)
    diverged = np.zeros(b, dtype=bool)
    tolerance = convergence_tolerance(cfg)
    steps: list[int | None] = []
    tic = time.perf_counter()
    for row in range(b):
        rec = calibrate(unit, setup, t, data.meas[row], target.start, cfg.calibration.kappa)
        err[row] = rec.x - truth
        cov[row] = rec.cov
        diverged[row] = rec.diverged
        steps.append(None if rec.diverged else convergence_step(err[row], tolerance))
    return UkfChunk(err, cov, diverged, steps, time.perf_counter() - tic)


def plan_bench(cfg: GyrosConfig, unit: GyroUnit, trials: int) -> tuple[BenchPlan, str]:
    """The plan of a run of ``trials`` FDI trials per group, and the note on the UKF run ("" if
    it runs; else why not, shown in summary.md)."""
    b = cfg.bench
    groups = tuple((k, float(s)) for k in b.kinds for s in b.sizes_sigma)
    plan = BenchPlan(groups, trials, unit.n, b.chunk_trials)
    if b.ukf_trials == 0:
        return plan, "bench.ukf_trials is 0: no UKF accuracy run"
    sc = cfg.scenario
    try:
        target = fault_target(cfg, unit, epochs(sc.duration_s, sc.dt_s))
    except ValueError as exc:
        return plan, f"no UKF accuracy run: {exc}"
    work = UkfWork(b.ukf_trials, target, setup_for(cfg, unit, target))
    return BenchPlan(groups, trials, unit.n, b.chunk_trials, work), ""


def _bar_label(backend: str, workers: int) -> str:
    """``gyros bench``, with ``, pool`` or ``, ray`` when the trials run in other processes."""
    if backend == "local" and workers <= 1:
        return "gyros bench"
    return f"gyros bench, {'pool' if backend == 'local' else backend}"


@dataclass
class _Collected:
    """The chunk results as they come back, kept in chunk order."""

    fdi: dict[int, list[FdiChunk]] = field(default_factory=dict)  # per group
    ukf: list[UkfChunk] = field(default_factory=list)
    fdi_epochs: int = 0
    fdi_seconds: float = 0.0


def run_bench(
    cfg: GyrosConfig,
    trials: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    backend: str = "local",
    workers: int | None = None,
) -> BenchResult:
    """The whole benchmark (see the module docstring).

    ``trials``, ``seed``, ``workers``: ``None`` takes ``bench.trials``, ``bench.seed``,
    ``bench.workers``. ``backend``: ``local`` (in this process when ``workers`` is 1, else a
    process pool) or ``ray`` (at ``bench.ray_address``); every backend gives the same numbers.
    """
    start_time = time.perf_counter()
    b = cfg.bench
    n_trials = b.trials if trials is None else trials
    seed = b.seed if seed is None else seed
    workers = b.workers if workers is None else workers
    if n_trials < 1:
        raise ValueError("trials must be at least 1")
    unit = build_unit(cfg)
    det = Detectors.build(unit, cfg.fdi)
    plan, note = plan_bench(cfg, unit, n_trials)
    task = partial(run_chunk, cfg, det, plan, seed)
    got = _Collected()
    with progress_bar(len(plan.groups) * n_trials, _bar_label(backend, workers), progress) as bar:
        ukf_done = bar.stage("UKF accuracy", plan.ukf.trials, "trials") if plan.ukf else None
        for res in run_chunks(task, plan.chunks(), backend, workers, b.ray_address):
            if isinstance(res, UkfChunk):
                got.ukf.append(res)
                if ukf_done is not None:
                    ukf_done(int(res.diverged.size))
                continue
            got.fdi.setdefault(res.group, []).append(res)
            got.fdi_epochs += res.epochs
            got.fdi_seconds += res.seconds
            bar(res.trials)
    counts = resample_counts(n_trials, b.bootstrap.resamples, seed)
    rows: list[BenchRow] = []
    for g, (kind, size) in enumerate(plan.groups):
        for m in METHODS:
            # chunk order: the trials of gyro 0, then gyro 1, …, as the bootstrap counts assume
            c = TrialCounts.concat([part.counts[m] for part in got.fdi[g]])
            rows.append(
                BenchRow(
                    method=m,
                    kind=kind,
                    size_sigma=size,
                    trials=int(c.pre_epochs.size),
                    metrics=summarize_counts(c, counts, b.bootstrap.level),
                    never_detected=int(np.sum(~np.isfinite(c.delay_s))),
                )
            )
    ukf = None if plan.ukf is None else _ukf_accuracy(cfg, unit, plan.ukf, got.ukf)
    return BenchResult(
        cfg=cfg,
        trials=n_trials,
        seed=seed,
        rows=rows,
        ukf=ukf,
        ukf_note=note,
        separability=unit.separability().lines(),
        fdi_epochs=got.fdi_epochs,
        fdi_seconds=got.fdi_seconds,
        runtime_s=time.perf_counter() - start_time,
        backend=backend,
        workers=workers,
    )


def _ukf_accuracy(
    cfg: GyrosConfig, unit: GyroUnit, work: UkfWork, parts: list[UkfChunk]
) -> UkfAccuracy:
    """RMS error, RMS sd and mean NEES per step over the UKF trials (chunks in trial order)."""
    m = work.trials
    err = np.concatenate([p.err for p in parts])
    cov = np.concatenate([p.cov for p in parts])
    k = err.shape[1]
    ne = nees(err, cov)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(err**2, axis=0)) / DISPLAY_SCALE
        sd = np.sqrt(np.nanmean(np.einsum("mkii->mki", cov), axis=0)) / DISPLAY_SCALE
    ok = np.isfinite(ne)
    mean_nees = np.where(
        ok.any(axis=0), np.nansum(ne, axis=0) / np.maximum(ok.sum(axis=0), 1), np.nan
    )
    sc = cfg.scenario
    t = epochs(sc.duration_s, sc.dt_s)
    start = work.target.start
    return UkfAccuracy(
        gyro=unit.ids[work.target.gyro],
        start_s=float(t[start]),
        t=t[start:] - t[start],
        rms=rms,
        sd=sd,
        nees=mean_nees,
        band=nees_band(4, m, cfg.bench.bootstrap.level),
        trials=m,
        diverged=int(sum(int(np.count_nonzero(p.diverged)) for p in parts)),
        converged_step=[s for p in parts for s in p.converged_step],
        seconds_per_step=sum(p.seconds for p in parts) / (m * k),
    )
