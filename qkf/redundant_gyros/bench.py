"""``qkf gyros bench``: detection and isolation of three-cross against the GLT over fault kinds
and sizes, and the UKF's calibration accuracy over Monte Carlo trials (docs/redundant_gyros.md,
"Bench").

Fault sizes are in σ units, σ the gyro's white-noise sd, and turn into a fault per kind so that
the fault's effect on the reading is about ``size · σ`` (:func:`bench_fault`). Trial k carries
the fault on gyro ``k mod n`` and draws its noise from ``(seed, k)``, so every kind and size
sees the same noise (common random numbers). Three detectors are scored on the same readings:
``threecross``, ``glt`` (per epoch) and ``glt_window`` (the configured window).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from qkf.core.montecarlo import chunk_ids, progress_bar
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
from qkf.redundant_gyros.pipeline import fault_target, setup_for
from qkf.redundant_gyros.scenario import body_rate, epochs, first_epoch, simulate
from qkf.redundant_gyros.ukf import DISPLAY_SCALE, calibrate

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
    fdi_seconds: float
    runtime_s: float


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


def run_bench(
    cfg: GyrosConfig, trials: int | None = None, seed: int | None = None, progress: bool = True
) -> BenchResult:
    """The whole benchmark (see the module docstring)."""
    start_time = time.perf_counter()
    b = cfg.bench
    n_trials = b.trials if trials is None else trials
    seed = b.seed if seed is None else seed
    unit = build_unit(cfg)
    det = Detectors.build(unit, cfg.fdi)
    dt = cfg.scenario.dt_s
    t = epochs(b.duration_s, dt)
    k0 = first_epoch(t, b.fault_time_s)
    rate = body_rate(cfg.scenario.body_rate, t)
    counts = resample_counts(n_trials, b.bootstrap.resamples, seed)
    rows: list[BenchRow] = []
    fdi_seconds, fdi_epochs = 0.0, 0
    groups = [(k, s) for k in b.kinds for s in b.sizes_sigma]
    with progress_bar(len(groups) * n_trials, "gyros bench", progress) as advance:
        for kind, size in groups:
            parts: dict[str, list[TrialCounts]] = {m: [] for m in METHODS}
            for gyro in range(unit.n):
                ids = np.arange(gyro, n_trials, unit.n)
                if ids.size == 0:
                    continue
                fault = bench_fault(kind, size, unit, gyro, rate, b)
                for chunk in chunk_ids(ids.size, b.chunk_trials):
                    data = simulate(unit, cfg.scenario.body_rate, [fault], t, seed, ids[chunk])
                    tic = time.perf_counter()
                    scored = _score_chunk(det, data.meas, gyro, k0, dt)
                    fdi_seconds += time.perf_counter() - tic
                    fdi_epochs += data.meas.shape[0] * t.size
                    for m in METHODS:
                        parts[m].append(scored[m])
                    advance(int(chunk.size))
            for m in METHODS:
                c = TrialCounts.concat(parts[m])
                rows.append(
                    BenchRow(
                        method=m,
                        kind=kind,
                        size_sigma=float(size),
                        trials=int(c.pre_epochs.size),
                        metrics=summarize_counts(c, counts, b.bootstrap.level),
                        never_detected=int(np.sum(~np.isfinite(c.delay_s))),
                    )
                )
    ukf, note = _ukf_accuracy(cfg, unit, seed)
    return BenchResult(
        cfg=cfg,
        trials=n_trials,
        seed=seed,
        rows=rows,
        ukf=ukf,
        ukf_note=note,
        separability=unit.separability().lines(),
        fdi_epochs=fdi_epochs,
        fdi_seconds=fdi_seconds,
        runtime_s=time.perf_counter() - start_time,
    )


def _ukf_accuracy(cfg: GyrosConfig, unit: GyroUnit, seed: int) -> tuple[UkfAccuracy | None, str]:
    """The UKF on the config's own scenario, started where the fault is (oracle isolation)."""
    m = cfg.bench.ukf_trials
    if m == 0:
        return None, "bench.ukf_trials is 0: no UKF accuracy run"
    sc = cfg.scenario
    t = epochs(sc.duration_s, sc.dt_s)
    try:
        target = fault_target(cfg, unit, t)
    except ValueError as exc:
        return None, f"no UKF accuracy run: {exc}"
    setup = setup_for(cfg, unit, target)
    data = simulate(unit, sc.body_rate, sc.faults, t, seed, np.arange(m))
    assert data.coeffs is not None
    truth = data.coeffs[target.start :, target.gyro]
    k = truth.shape[0]
    err = np.full((m, k, 4), np.nan)
    cov = np.full((m, k, 4, 4), np.nan)
    diverged = 0
    tolerance = convergence_tolerance(cfg)
    steps: list[int | None] = []
    tic = time.perf_counter()
    for trial in range(m):
        rec = calibrate(unit, setup, t, data.meas[trial], target.start, cfg.calibration.kappa)
        err[trial] = rec.x - truth
        cov[trial] = rec.cov
        diverged += int(rec.diverged)
        steps.append(None if rec.diverged else convergence_step(err[trial], tolerance))
    per_step = (time.perf_counter() - tic) / (m * k)
    ne = nees(err, cov)
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(np.nanmean(err**2, axis=0)) / DISPLAY_SCALE
        sd = np.sqrt(np.nanmean(np.einsum("mkii->mki", cov), axis=0)) / DISPLAY_SCALE
    ok = np.isfinite(ne)
    mean_nees = np.where(
        ok.any(axis=0), np.nansum(ne, axis=0) / np.maximum(ok.sum(axis=0), 1), np.nan
    )
    result = UkfAccuracy(
        gyro=unit.ids[target.gyro],
        start_s=float(t[target.start]),
        t=t[target.start :] - t[target.start],
        rms=rms,
        sd=sd,
        nees=mean_nees,
        band=nees_band(4, m, cfg.bench.bootstrap.level),
        trials=m,
        diverged=diverged,
        converged_step=steps,
        seconds_per_step=per_step,
    )
    return result, ""
