"""``qkf fuse``: star-camera + angular-accelerometer fusion (docs/sca_fusion.md).

Mounted on the top-level app as a command; heavy imports happen inside the command. Exit codes:
0 success, 2 bad input (config, data file, option; nothing written), 1 anything else.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from qkf.core.cli_support import OverwriteOption, SetOption, fail, out, out_dir, seed_option

if TYPE_CHECKING:
    from qkf.core.least_squares import IterationInfo

app = typer.Typer(add_completion=False, help="Star-camera + angular-accelerometer fusion.")


@app.command("fuse")
def fuse_cmd(
    config: Annotated[
        str, typer.Argument(help="Fusion config: a preset name (sca_acc_fusion) or a YAML path.")
    ],
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")],
    sca: Annotated[
        Path | None, typer.Option("--sca", help="Star camera CSV: t_s, q_x, q_y, q_z, q_w.")
    ] = None,
    acc: Annotated[
        Path | None,
        typer.Option("--acc", help="Angular accelerometer CSV: t_s, dw_x, dw_y, dw_z (rad/s²)."),
    ] = None,
    seed: Annotated[
        int | None, typer.Option(help="Simulation seed (config: simulation.seed).")
    ] = None,
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    overwrite: OverwriteOption = False,
) -> None:
    """Star-camera + angular-accelerometer attitude fusion (least squares per arc).

    Variance components and Huber weights as GROOPS. Without --sca/--acc, simulate from the
    config and compare with the truth. Writes fused.csv, variance_components.csv, solution.csv,
    epoch_sigma.csv, acc_calibrated.csv, summary.md, run.json and plots; --out must be new,
    empty or (with --overwrite) an earlier fuse run, replaced whole.
    """
    from qkf.core.config import ConfigError
    from qkf.core.io import OutputError
    from qkf.sca_fusion.config import load_config

    if (sca is None) != (acc is None):
        raise fail("give both --sca and --acc (or neither, to simulate)")
    seed_option(seed)
    sets = list(set_ or []) + ([f"simulation.seed={seed}"] if seed is not None else [])
    try:
        cfg = load_config(config, sets)
    except ConfigError as exc:
        raise fail(str(exc)) from None
    folder = out_dir(out_path, "fuse", overwrite)

    from qkf.sca_fusion.data import DataError, read_acc, read_sca

    data = None
    if sca is not None and acc is not None:
        try:
            tol = cfg.data.time_match_tolerance_s
            data = (read_sca(sca, cfg.data.quaternion_norm_tolerance, tol), read_acc(acc, tol))
            from qkf.sca_fusion.data import check_pair

            # rows, overlap, coverage: before any work
            check_pair(*data, cfg, cfg.data.min_overlap_fraction)
        except DataError as exc:
            raise fail(str(exc)) from None

    from qkf.core.banded import NotPositiveDefiniteError
    from qkf.sca_fusion.fusion import run_fusion
    from qkf.sca_fusion.report import write_outputs

    try:
        with _IterationBar(cfg.estimator.iteration_count, not quiet) as bar:
            run = run_fusion(cfg, data, bar.on_arc, bar.on_iteration)
    except NotPositiveDefiniteError as exc:
        raise fail(f"the normal equations of an arc cannot be solved: {exc}", code=1) from None
    if not run.solutions:
        raise fail("no arc to fuse: " + ("; ".join(run.skipped) or "no epochs"))
    source = "simulated" if data is None else f"recorded ({sca}, {acc})"
    try:
        write_outputs(cfg, run, folder, source)
    except OutputError as exc:
        raise fail(f"--out: {exc}", code=1) from None
    text = (folder / "summary.md").read_text()
    out.print(text, soft_wrap=True, markup=False, highlight=False)
    out.print(f"fused {len(run.solutions)} arc(s) in {run.runtime_s:.2f} s; wrote {folder}/")


class _IterationBar:
    """A rich progress bar over the iterations of each arc (on stderr); ``on_arc`` and
    ``on_iteration`` are the callbacks of :func:`qkf.sca_fusion.fusion.run_fusion`."""

    def __init__(self, iterations: int, enabled: bool) -> None:
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TaskID,
            TextColumn,
            TimeElapsedColumn,
        )

        from qkf.core.cli_support import err

        self.iterations = iterations
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("iterations  σ₀ {task.fields[sigma0]}"),
            TimeElapsedColumn(),
            console=err,
            disable=not enabled,
        )
        self.task: TaskID | None = None
        self.done = 0

    def __enter__(self) -> _IterationBar:
        self.progress.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self._finish()
        self.progress.__exit__(None, None, None)

    def _finish(self) -> None:
        """Close the bar of the arc just solved at the iterations it took."""
        if self.task is not None:
            self.progress.update(self.task, total=self.done, completed=self.done)

    def on_arc(self, k: int, count: int) -> None:
        self._finish()
        self.done = 0
        self.task = self.progress.add_task(
            f"arc {k + 1}/{count}", total=self.iterations, sigma0="–"
        )

    def on_iteration(self, info: IterationInfo) -> None:
        self.done = info.iteration
        if self.task is not None:
            self.progress.update(self.task, completed=info.iteration, sigma0=f"{info.sigma0:.5g}")
