"""Speed of the redundant-gyro FDI and of the calibration UKF (docs/redundant_gyros.md).

Run: ``.venv/bin/python benchmarks/gyros_speed.py`` (defaults: 1,000 trials × 6,000 epochs).

* FDI: three-cross (feature, band counts, binomial test), the windowed parity GLT and the
  reconfigured output rate (:func:`qkf.redundant_gyros.fdi.run_fdi`) over ``--trials`` ×
  ``--epochs``, in chunks of ``--chunk`` trials to bound memory. The simulation of the readings
  is timed separately and not counted. Goal: under 30 s.
* UKF: cost per step of :func:`qkf.redundant_gyros.ukf.calibrate` (filterpy's
  ``UnscentedKalmanFilter`` plus the per-step measurement variance, symmetrisation and
  records) against a plain filterpy loop in the same run — the same filter, sigma points and
  measurement function, ``predict(); update(z, rate=…)`` with a fixed ``R`` and nothing else.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from qkf.core.montecarlo import chunk_ids
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.fdi import Detectors, run_fdi
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import fault_target, setup_for
from qkf.redundant_gyros.scenario import simulate
from qkf.redundant_gyros.ukf import (
    DIM,
    calibrate,
    measurement,
    measurement_variance,
    triad_rate,
)

GOAL_S = 30.0


def fdi_speed(trials: int, n_epochs: int, chunk: int) -> None:
    cfg = load_config("five_gyros_s_bias")
    unit = build_unit(cfg)
    tic = time.perf_counter()
    det = Detectors.build(unit, cfg.fdi)
    build_s = time.perf_counter() - tic
    t = np.arange(n_epochs) * cfg.scenario.dt_s
    sim_s = fdi_s = 0.0
    flagged = 0
    for ids in chunk_ids(trials, chunk):
        tic = time.perf_counter()
        data = simulate(unit, cfg.scenario.body_rate, cfg.scenario.faults, t, 0, ids)
        sim_s += time.perf_counter() - tic
        tic = time.perf_counter()
        res = run_fdi(det, data.meas)
        fdi_s += time.perf_counter() - tic
        flagged += int(np.count_nonzero(res.glt.detected))
    epochs = trials * n_epochs
    print(f"FDI: {trials} trials × {n_epochs} epochs = {epochs:,} trial-epochs, chunks of {chunk}")
    print(f"  detectors built once: {build_s:.2f} s (three-cross null probabilities)")
    print(f"  simulation (not counted): {sim_s:.2f} s")
    print(
        f"  three-cross + GLT + reconfiguration: {fdi_s:.2f} s "
        f"({1e9 * fdi_s / epochs:.0f} ns per trial-epoch); goal < {GOAL_S:.0f} s: "
        f"{'met' if fdi_s < GOAL_S else 'NOT met'}"
    )
    print(f"  (GLT flagged {flagged:,} trial-epochs)")


def ukf_speed(steps: int, repeats: int) -> None:
    cfg = load_config("five_gyros_s_bias")
    unit = build_unit(cfg)
    sc = cfg.scenario
    t = np.arange(steps + 1) * sc.dt_s
    target = fault_target(cfg, unit, t)
    setup = setup_for(cfg, unit, target)
    data = simulate(unit, sc.body_rate, sc.faults, t, 0, [0])
    meas = data.meas[0]
    rates = triad_rate(unit, setup, meas)
    z = meas[:, setup.gyro]
    r_fixed = measurement_variance(setup, setup.x0)

    def ours() -> None:
        calibrate(unit, setup, t, meas, 0)

    def plain() -> None:
        points = MerweScaledSigmaPoints(
            DIM, alpha=setup.alpha, beta=setup.beta, kappa=setup.kappa_points
        )
        kf = UnscentedKalmanFilter(
            dim_x=DIM,
            dim_z=1,
            dt=sc.dt_s,
            hx=measurement,
            fx=lambda x, dt: x,
            points=points,
        )
        kf.x = setup.x0.copy()
        kf.P = np.diag(setup.p0_sd**2)
        kf.Q = np.diag(setup.q_sd**2) * sc.dt_s
        kf.R = np.array([[r_fixed]])
        for k in range(t.size):
            kf.predict()
            kf.update(z[k : k + 1], rate=rates[k], setup=setup)

    def best(fn: object) -> float:
        times = []
        for _ in range(repeats):
            tic = time.perf_counter()
            fn()  # type: ignore[operator]
            times.append(time.perf_counter() - tic)
        return min(times) / t.size

    ours_s, plain_s = best(ours), best(plain)
    print(f"UKF: {t.size} steps, best of {repeats}")
    print(f"  calibrate (ours): {1e6 * ours_s:.0f} µs per step")
    print(f"  plain filterpy loop: {1e6 * plain_s:.0f} µs per step")
    print(f"  ratio ours / plain: {ours_s / plain_s:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--epochs", type=int, default=6000)
    ap.add_argument("--chunk", type=int, default=50)
    ap.add_argument("--ukf-steps", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    fdi_speed(args.trials, args.epochs, args.chunk)
    ukf_speed(args.ukf_steps, args.repeats)


if __name__ == "__main__":
    main()
