"""Speed and memory of the star-camera + angular-accelerometer fusion (docs/sca_fusion.md):
one 24-hour arc at 1 Hz (86,400 epochs), the preset's noise and outliers, GROOPS defaults
(at most 15 iterations). Targets: under 30 s and under 2 GB.

Run: ``.venv/bin/python benchmarks/fusion_speed.py [--hours 24] [--no-trace]``.

It prints the time of the simulation and of the fusion (all iterations, covariance included),
the peak resident memory of the process (``ru_maxrss``), the peak of the Python/numpy heap
during the fusion (``tracemalloc``, a second, traced run), and as the in-run reference the time
of an arc ten times shorter: the ratio shows how the cost scales (10 for linear cost).
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc

from qkf.sca_fusion.config import load_config
from qkf.sca_fusion.data import Series
from qkf.sca_fusion.fusion import ArcSolution, arcs_from_series, fuse_arc
from qkf.sca_fusion.scenario import simulate


def _fuse(hours: float) -> tuple[float, float, ArcSolution]:
    cfg = load_config(
        "sca_acc_fusion",
        [
            f"simulation.duration_s={hours * 3600.0 - 1.0}",
            "simulation.sca_gaps=[]",
            "simulation.data_gaps=[]",
        ],
    )
    t0 = time.perf_counter()
    sim = simulate(cfg.simulation)
    arcs = arcs_from_series(
        Series("", sim.sca_t, sim.sca_q), Series("", sim.acc_t, sim.acc), cfg
    ).arcs
    t1 = time.perf_counter()
    (arc,) = arcs
    sol = fuse_arc(arc, cfg.estimator)
    return t1 - t0, time.perf_counter() - t1, sol


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--no-trace", action="store_true", help="skip the tracemalloc run")
    args = ap.parse_args()
    _fuse(0.1)  # compile the numba kernels and warm the caches
    _, t_ref, sol_ref = _fuse(args.hours / 10.0)
    t_sim, t_fuse, sol = _fuse(args.hours)
    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2  # KiB on Linux
    n = sol.t.size
    print(f"arc: {n} epochs ({args.hours:g} h at 1 Hz), {sol.iterations} iterations")
    print(f"simulation: {t_sim:.2f} s")
    print(
        f"fusion: {t_fuse:.2f} s ({t_fuse / sol.iterations:.2f} s per iteration); "
        f"target < 30 s: {'ok' if t_fuse < 30.0 else 'MISSED'}"
    )
    scale = (t_fuse / sol.iterations) / (t_ref / sol_ref.iterations)
    print(
        f"reference: {sol_ref.t.size} epochs in {t_ref:.2f} s ({sol_ref.iterations} iterations); "
        f"cost per iteration scales by {scale:.1f} for 10x the epochs"
    )
    print(
        f"peak resident memory (process): {rss_gb:.2f} GB; "
        f"target < 2 GB: {'ok' if rss_gb < 2.0 else 'MISSED'}"
    )
    if not args.no_trace:
        tracemalloc.start()
        _fuse(args.hours)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        print(f"peak traced heap during simulation + fusion (tracemalloc): {peak / 1024**3:.2f} GB")


if __name__ == "__main__":
    main()
