"""The toy problem's commands: a Typer ``app`` that only the top-level command line mounts
(``app.add_typer(toy_app, name="toy")``, as qkf/cli.py mounts ``gyros``). Exit codes: 0 success,
2 bad input (config, option; nothing written), 1 anything else."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

from qkf.core.cli_support import (
    OverwriteOption,
    SetOption,
    fail,
    out,
    out_dir,
    refused,
    seed_option,
)

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Toy: a scalar random walk.")


@app.command("bench")
def bench_cmd(
    config: Annotated[str, typer.Argument(help="A preset name (toy_walk) or a YAML path.")],
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")],
    trials: Annotated[int | None, typer.Option(help="Trials (bench.trials).")] = None,
    seed: Annotated[int | None, typer.Option(help="Seed (bench.seed).")] = None,
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    backend: Annotated[str, typer.Option(help="local or ray.")] = "local",
    workers: Annotated[int, typer.Option(help="local backend: worker processes.")] = 1,
    overwrite: OverwriteOption = False,
) -> None:
    """Monte Carlo of the Kalman filter: rms.csv (RMS, own sd, NEES and its band), summary.md,
    run.json."""
    # heavy imports inside the command: mounting the app must cost nothing
    from qkf.core.montecarlo import BACKENDS
    from tests.example_problem.toy_estimation.benchmark import run_bench
    from tests.example_problem.toy_estimation.config import load_config
    from tests.example_problem.toy_estimation.report import KIND, write_bench

    with refused():  # every check before the output folder is touched
        cfg = load_config(config, list(set_ or []))
    if trials is not None and trials < 1:
        raise fail("--trials must be at least 1")
    seed_option(seed)
    if backend not in BACKENDS:
        raise fail(f"--backend: {backend!r} is not {' or '.join(BACKENDS)}")
    if workers < 1:
        raise fail("--workers must be at least 1")
    folder = out_dir(out_path, KIND, overwrite)
    res = run_bench(cfg, trials, seed, backend=backend, workers=workers, progress=not quiet)
    write_bench(res, folder, list(sys.argv))
    out.print((folder / "summary.md").read_text(), markup=False, highlight=False)
    out.print(f"wrote {folder}/")
