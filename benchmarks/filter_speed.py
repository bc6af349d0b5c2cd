"""Speed of the batched transfer-alignment filter against a plain loop over filterpy.

Run: ``.venv/bin/python benchmarks/filter_speed.py`` (or ``make speed``).

For each batch size B the same 15-state filter runs over the epochs of the ``paper`` scenario:

* ``batched``: :class:`qkf.transfer_alignment.filter.TransferAlignmentKF`, all B trials at
  once (model, update, reset and propagation included; compiled kernel, trials spread over the
  cores);
* ``filterpy``: one ``filterpy.kalman.KalmanFilter`` per trial, ``predict(F=Φ, Q=Q)`` and
  ``update(z, R=R, H=H)`` each epoch with the same transfer-alignment matrices, evaluated
  beforehand (outside the timing) so that only filterpy's own cost is counted: the most
  favourable reference for filterpy. Its cost does not depend on B (a plain loop), so it is
  measured on ``min(B, --ref-trials)`` trials;
* ``filterpy+model`` (once): the complete per-trial reference
  ``qkf.transfer_alignment.reference``, which also evaluates Φ, Q_d, H, R and the attitude reset
  per step in numpy/scipy.

It prints filter-steps per second (trials × epochs / s), the ratio batched/filterpy as
``speedup_vs_filterpy: X`` and the peak memory allocated by the batched filter (filter state,
kernel scratch and per-block records; the simulated input data are not counted), traced in a
separate untimed run.
"""

from __future__ import annotations

import argparse
import os
import time
import tracemalloc
from pathlib import Path

import numba
import numpy as np
from filterpy.kalman import KalmanFilter

from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF
from qkf.transfer_alignment.model import calibration_matrix, discretize, measurement_model
from qkf.transfer_alignment.reference import run_reference
from qkf.transfer_alignment.scenario import simulate, true_rates

ROOT = Path(__file__).resolve().parents[1]


def batched_rate(cfg, trials: int, block: int, repeats: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """Filter-steps per second of the batched core and the peak traced memory (MiB)."""
    data = simulate(cfg, 0, trials)
    params = FilterParams.from_config(cfg)
    n = data.n_epochs
    warm = TransferAlignmentKF(params, trials)  # compile / load the kernel outside the timing
    warm.initialize(data.ads_q[:, 0])
    warm.step_data(data, 0, min(n, 5))

    def run() -> None:
        kf = TransferAlignmentKF(params, trials)
        kf.initialize(data.ads_q[:, 0])
        for k in range(0, n, block):
            kf.step_data(data, k, min(n, k + block))

    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - t0)
    # Memory in a separate, untimed run: tracing every allocation slows the kernel tenfold.
    tracemalloc.start()
    run()
    peak = tracemalloc.get_traced_memory()[1] / 2**20
    tracemalloc.stop()
    return trials * n / best, peak


def filterpy_rate(cfg, trials: int, repeats: int = 2) -> float:  # type: ignore[no-untyped-def]
    """Filter-steps per second of filterpy's predict/update with precomputed matrices (best of
    ``repeats``)."""
    params = FilterParams.from_config(cfg)
    data = simulate(cfg, 0, trials)
    n = data.n_epochs
    w = true_rates(cfg.scenario)
    a = np.broadcast_to(np.linalg.inv(np.eye(3) + calibration_matrix(np.zeros(9))), (n, 3, 3))
    phi, qd = discretize(w, a, params.dt, params.sigma_v, params.sigma_u, params.qp0)
    h, r = measurement_model(
        w, a, params.dt, params.sigma_a, params.sigma_r, params.sigma_v, params.use_rate
    )
    m = h.shape[1]
    z = np.concatenate([np.zeros((trials, n, 3)), data.ads_rate - w], axis=2)[..., :m]
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for b in range(trials):
            kf = KalmanFilter(dim_x=15, dim_z=m)
            kf.x = np.zeros(15)
            kf.P = np.diag(params.p0_sigma**2)
            for k in range(n):
                if data.has_meas[k]:
                    kf.update(z[b, k], R=r[k], H=h[k])
                    kf.x = np.zeros(15)  # error-state reset, as the filter does
                kf.predict(F=phi[k], Q=qd[k])
        best = min(best, time.perf_counter() - t0)
    return trials * n / best


def full_reference_rate(cfg, epochs: int) -> float:  # type: ignore[no-untyped-def]
    params = FilterParams.from_config(cfg)
    data = simulate(cfg, 0, 1)
    sl = slice(0, epochs)
    t0 = time.perf_counter()
    run_reference(
        params, data.gyro[0, sl], data.ads_q[0, sl], data.ads_rate[0, sl], data.has_meas[sl]
    )
    return epochs / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", default="paper", help="preset name or YAML path")
    ap.add_argument("--batches", default="1,16,256,1024", help="comma-separated batch sizes B")
    ap.add_argument("--ref-trials", type=int, default=4, help="trials timed for filterpy")
    ap.add_argument("--block", type=int, default=100, help="epochs per kernel call")
    ap.add_argument("--set", action="append", default=[], help="config override key=value")
    args = ap.parse_args()
    cfg = load_config(args.config, args.set)
    batches = [int(b) for b in args.batches.split(",")]
    print(
        f"config {cfg.name}: {cfg.scenario.duration_s:g} epochs, matching {cfg.filter.matching}; "
        f"numba threads {numba.get_num_threads()}, cpus {os.cpu_count()}"
    )
    full = full_reference_rate(cfg, 300)
    print(f"filterpy+model reference (qkf.transfer_alignment.reference): {full:,.0f} steps/s")
    print(
        f"{'B':>6} {'batched steps/s':>16} {'us/trial-step':>14} {'filterpy steps/s':>17} "
        f"{'peak MiB':>9}  speedup"
    )
    for b in batches:
        rate, peak = batched_rate(cfg, b, args.block, repeats=3)
        ref = filterpy_rate(cfg, min(b, args.ref_trials))
        print(
            f"{b:>6} {rate:>16,.0f} {1e6 / rate:>14.2f} {ref:>17,.0f} {peak:>9.1f}  "
            f"speedup_vs_filterpy: {rate / ref:.1f}  (vs filterpy+model: {rate / full:.0f})"
        )


if __name__ == "__main__":
    main()
