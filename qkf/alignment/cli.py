"""``qkf align``: attitude-independent alignment calibration (docs/alignment.md).

Mounted as a top-level command by :mod:`qkf.cli`. Exit codes: 0 success, 2 bad input (config,
data file, option: one message naming the file and the field or row and column, nothing
written), 1 anything else.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from qkf.core.cli_support import OverwriteOption, SetOption, fail, out, out_dir

app = typer.Typer(add_completion=False, help="Alignment calibration of vector sensors.")


@app.command("align")
def align_cmd(
    config: Annotated[
        str,
        typer.Argument(
            help="Sensors and settings: a preset name (alignment_three_sensors) or a YAML path."
        ),
    ],
    out_path: Annotated[
        str,
        typer.Option(
            "--out", help="Output directory: new, empty or (--overwrite) an earlier align run."
        ),
    ],
    data: Annotated[
        Path | None,
        typer.Option(
            "--data",
            help="Observations CSV: t_s, sensor, w_x, w_y, w_z, r_x, r_y, r_z. Without it the "
            "config's simulation is run and the errors against its truth are reported.",
        ),
    ] = None,
    set_: SetOption = None,
    plot: Annotated[bool, typer.Option(help="Write residuals.png.")] = True,
    overwrite: OverwriteOption = False,
) -> None:
    """Alignment calibration of vector sensors, attitude-independent.

    The alignments relative to the reference sensor, from the angles between simultaneous
    observations (Gauss–Newton with a prelaunch prior): alignment.csv, observability.csv,
    summary.md, residuals.png (and data.csv when simulated).
    """
    from qkf.alignment.config import load_config
    from qkf.alignment.data import DataError, read_data
    from qkf.alignment.report import write_outputs
    from qkf.alignment.scenario import simulate
    from qkf.alignment.solve import SolveError, solve
    from qkf.core.config import ConfigError
    from qkf.core.io import OutputError

    try:
        cfg = load_config(config, list(set_ or []))
    except ConfigError as exc:
        raise fail(str(exc)) from None
    folder = out_dir(out_path, "align", overwrite)
    truth = None
    if data is not None:
        try:
            obs = read_data(data, cfg.names, cfg.data.unit_tolerance, cfg.data.time_tolerance_s)
        except DataError as exc:
            raise fail(str(exc)) from None
        source = f"`{data}`"
    else:
        obs, truth = simulate(cfg)
        sim = cfg.simulation
        source = (
            f"simulation (seed {sim.seed}, {sim.epochs} epochs every {sim.dt_s:g} s, "
            "random attitudes)"
        )
    try:
        sol = solve(cfg, obs)
    except SolveError as exc:
        raise fail(f"{data if data is not None else config}: {exc}", code=1) from None
    try:
        write_outputs(folder, cfg, obs, sol, truth, source, plot=plot)
    except OutputError as exc:
        raise fail(f"--out: {exc}", code=1) from None
    text = (folder / "summary.md").read_text(encoding="utf-8")
    out.print(text, soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {folder}/")
