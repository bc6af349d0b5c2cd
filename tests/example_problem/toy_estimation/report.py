"""The toy bench's run folder: rms.csv, summary.md and run.json, swapped in whole."""

from __future__ import annotations

from pathlib import Path

from qkf.core.io import atomic_write_text, csv_text, staged_directory
from qkf.core.manifest import manifest, write_manifest
from tests.example_problem.toy_estimation.benchmark import BenchResult

KIND = "toy-bench"  # run.json's kind: --out may replace an earlier run of this kind only
COLUMNS = ("t_s", "rms_u", "sd_u", "nees", "band_lo", "band_hi")


def summary_md(res: BenchResult) -> str:
    return (
        f"# toy bench: {res.cfg.name}\n\n{res.trials} trials, seed {res.seed}. Final RMS error "
        f"{res.rms[-1]:.4g} u against the filter's own {res.sd[-1]:.4g} u; trial-averaged NEES "
        f"inside its {100 * res.cfg.bench.level:g} % χ² band [{res.band[0]:.3g}, "
        f"{res.band[1]:.3g}] at {100 * res.in_band:.1f} % of the epochs.\n"
    )


def write_bench(res: BenchResult, out_dir: str | Path, command: list[str] | None = None) -> Path:
    """Write the run into ``out_dir`` (nothing there until it is complete); returns it."""
    rows = (
        (float(t), float(r), float(s), float(e), *res.band)
        for t, r, s, e in zip(res.t, res.rms, res.sd, res.nees, strict=True)
    )
    info = manifest(
        KIND,
        res.cfg.model_dump(mode="json"),
        command,
        trials=res.trials,
        seed=res.seed,
        backend=res.backend,
        workers=res.workers,
    )
    with staged_directory(out_dir) as stage:
        atomic_write_text(stage / "rms.csv", csv_text(COLUMNS, rows))
        atomic_write_text(stage / "summary.md", summary_md(res))
        write_manifest(stage, info)
    return Path(out_dir)
