"""Speed and memory of ``qkf bench --data`` on a day of recorded data (docs/recorded_data.md).

Run: ``.venv/bin/python benchmarks/recorded_speed.py [--hours 24] [--rate-hz 10] [--truth]``.

It writes a recorded run of ``--hours`` at ``--rate-hz`` (by default 864,000 epochs, from the
``paper`` scenario at that step; no truth columns unless ``--truth``, like telemetry) with
``qkf record``, then times ``qkf bench paper --data FILE --methods kf`` in a child process: wall
time, and the peak resident memory of the child (``ru_maxrss`` of the finished child, which
counts reading, filtering, the quality measures, the plots and the streamed ``estimates.csv``).
The goals: under 60 s, under 2 GB. ``reference_s`` is the time of the same child doing only
``import qkf.transfer_alignment.recorded.run`` (start-up, numba cache load), measured in the
same run, so ``bench_s − reference_s`` is the work itself.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
QKF = [sys.executable, "-m", "qkf"]


def timed(cmd: list[str]) -> tuple[float, float]:
    """Wall time (s) and peak RSS (MiB) of ``cmd`` run as a child (one child at a time)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # KiB on Linux
    if peak < before:  # pragma: no cover - maxrss never decreases
        peak = before
    return wall, peak / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--rate-hz", type=float, default=10.0)
    ap.add_argument("--truth", action="store_true", help="write and use the truth columns")
    ap.add_argument("--methods", default="kf")
    ap.add_argument("--keep", type=Path, default=None, help="keep the run folder here")
    args = ap.parse_args()
    dt = 1.0 / args.rate_hz
    duration = args.hours * 3600.0
    sets = [f"scenario.dt_s={dt!r}", f"scenario.duration_s={duration!r}"]
    with tempfile.TemporaryDirectory(prefix="qkf_recorded_speed_") as tmp:
        data = Path(tmp) / "day.csv"
        t0 = time.perf_counter()
        truth = "--truth" if args.truth else "--no-truth"
        cmd = [*QKF, "record", "paper", "--out", str(data), truth]
        for s in sets:
            cmd += ["--set", s]
        subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        write_s = time.perf_counter() - t0
        size_mb = data.stat().st_size / 2**20
        epochs = round(duration / dt)
        print(f"wrote {epochs:,} epochs ({size_mb:.0f} MiB) in {write_s:.1f} s")
        ref_s, ref_mb = timed([sys.executable, "-c", "import qkf.transfer_alignment.recorded.run"])
        out = args.keep if args.keep is not None else Path(tmp) / "run"
        bench_cmd = [*QKF, "bench", "paper", "--data", str(data), "--methods", args.methods]
        bench_cmd += ["--out", str(out), "--quiet"]
        bench_s, bench_mb = timed(bench_cmd)
        est_mb = (out / "estimates.csv").stat().st_size / 2**20
    print(f"reference_s: {ref_s:.2f}  (start-up only; peak {ref_mb:.0f} MiB)")
    print(f"bench_s: {bench_s:.2f}  (goal < 60)")
    print(f"peak_rss_mib: {bench_mb:.0f}  (goal < 2048)")
    print(f"estimates.csv: {est_mb:.0f} MiB")
    print(f"epochs_per_s: {epochs / bench_s:,.0f}")
    print(f"cores: {os.cpu_count()}  methods: {args.methods}  truth: {args.truth}")


if __name__ == "__main__":
    main()
