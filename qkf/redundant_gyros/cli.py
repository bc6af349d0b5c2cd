"""``qkf gyros``: redundant skewed gyros — feature table, FDI and calibration run, benchmark
(docs/redundant_gyros.md). Mounted by :mod:`qkf.cli`; heavy imports happen inside the commands.

Exit codes as everywhere: 0 success, 2 bad input (config, data file, option: one message naming
the file and the field, row or column; nothing written), 1 anything else.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from qkf.core.cli_support import (
    BackendOption,
    OverwriteOption,
    SetOption,
    backend_options,
    fail,
    out,
    out_dir,
    out_file,
    seed_option,
)
from qkf.core.config import ConfigError

if TYPE_CHECKING:
    from qkf.redundant_gyros.config import GyrosConfig

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Redundant skewed gyros: three-cross and parity-GLT fault isolation, UKF calibration.",
)

ConfigArgument = Annotated[
    str, typer.Argument(help="Gyro config: a preset name (five_gyros) or a YAML path.")
]


def _load(config: str, sets: list[str] | None) -> GyrosConfig:
    from qkf.redundant_gyros import load_config

    try:
        return load_config(config, list(sets or []))
    except ConfigError as exc:
        raise fail(str(exc)) from None


def _report_separability(cfg: GyrosConfig) -> None:
    """What the geometry cannot tell apart, printed before any work."""
    from qkf.redundant_gyros.geometry import build_unit

    for line in build_unit(cfg).separability().lines():
        out.print(f"note: {line}", highlight=False, markup=False)


@app.command("features")
def features_cmd(
    config: ConfigArgument,
    out_path: Annotated[str, typer.Option("--out", help="CSV file to write.")],
    set_: SetOption = None,
) -> None:
    """Three-cross feature value per gyro: design geometry, and with the nominal errors left
    uncompensated (gyro, feature_nominal, feature_with_errors)."""
    cfg = _load(config, set_)
    from qkf.redundant_gyros.report import FEATURE_COLUMNS, write_features

    path = out_file(out_path, ",".join(FEATURE_COLUMNS))
    import numpy as np

    from qkf.redundant_gyros.geometry import build_unit
    from qkf.redundant_gyros.threecross import feature_table

    unit = build_unit(cfg)
    rows = feature_table(unit, cfg.features.fault_deg_s, np.asarray(cfg.features.body_rate_deg_s))
    write_features(path, rows)
    for r in rows:
        out.print(f"{r.gyro:>4}  {r.nominal:10.4f}  {r.with_errors:10.4f}", highlight=False)
    for line in unit.separability().lines():
        out.print(f"note: {line}", highlight=False, markup=False)
    out.print(f"wrote {path}")


@app.command("run")
def run_cmd(
    config: ConfigArgument,
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")],
    data: Annotated[
        Path | None,
        typer.Option("--data", help="Recorded readings: t_s and one column per gyro id, deg/s."),
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of the simulation (run.seed).")] = None,
    set_: SetOption = None,
    overwrite: OverwriteOption = False,
) -> None:
    """Per epoch: feature, isolated gyro (three-cross, GLT), output model and rate; then the UKF
    calibration of the isolated gyro. Writes fdi.csv, calibration.csv, summary.md, plots."""
    cfg = _load(config, set_)
    seed_option(seed)
    folder = out_dir(out_path, "gyros-run", overwrite)
    from qkf.redundant_gyros.data import DataError, load_readings
    from qkf.redundant_gyros.pipeline import run
    from qkf.redundant_gyros.report import write_run

    readings = None
    if data is not None:
        try:
            readings = load_readings(data, cfg.unit.ids())
        except DataError as exc:
            raise fail(str(exc)) from None
        source = f"recorded ({data})"
    else:
        source = f"simulated (seed {cfg.run.seed if seed is None else seed})"
    _report_separability(cfg)  # only once the input is known to be usable
    res = run(cfg, readings, seed)
    write_run(res, folder, source, list(sys.argv))
    out.print((folder / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {folder}/")


@app.command("bench")
def bench_cmd(
    config: ConfigArgument,
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")] = (
        "results/gyros_bench"
    ),
    trials: Annotated[
        int | None, typer.Option(help="Trials per fault kind and size (bench.trials).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Seed (bench.seed).")] = None,
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    backend: BackendOption = "local",
    workers: Annotated[
        int | None,
        typer.Option(help="local backend: worker processes (config: bench.workers)."),
    ] = None,
    overwrite: OverwriteOption = False,
) -> None:
    """Three-cross vs GLT over fault kinds and sizes (σ units) with bootstrap intervals, and the
    UKF's accuracy and NEES over trials: bench.csv, ukf.csv, summary.md, bench.png, ukf.png,
    run.json. Every backend gives the same numbers."""
    from qkf.redundant_gyros.config import MAX_TRIALS

    cfg = _load(config, set_)
    if trials is not None and not 1 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 1 and {MAX_TRIALS:,}")
    seed_option(seed)
    from qkf.redundant_gyros.config import check_workload

    try:
        check_workload(cfg, trials)
    except ConfigError as exc:
        raise fail(f"{config}: {exc}") from None
    # the same checks and messages as qkf bench, before the output folder is touched
    backend_options(backend, workers)
    folder = out_dir(out_path, "gyros-bench", overwrite)
    _report_separability(cfg)
    from qkf.redundant_gyros.benchmark import run_bench
    from qkf.redundant_gyros.report import write_bench

    res = run_bench(cfg, trials, seed, progress=not quiet, backend=backend, workers=workers)
    write_bench(res, folder, list(sys.argv))
    out.print((folder / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {folder}/")
