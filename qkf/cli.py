"""Command line: ``qkf crlb`` and ``qkf bench`` (SPEC §8).

Exit codes: 0 success, 2 bad input (config, option), 1 anything else.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from qkf.transfer_alignment.config import Config, ConfigError, load_config

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="qkf: adaptive Kalman filtering gym for in-orbit gyro calibration.",
)
err = Console(stderr=True)
out = Console()

SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override a config value: dotted.key=value (YAML value)."),
]


def _fail(msg: str, code: int = 2) -> typer.Exit:
    err.print(f"[bold red]error:[/] {msg}", highlight=False, markup=True)
    return typer.Exit(code)


def _load(config: Path, sets: list[str] | None) -> Config:
    try:
        return load_config(config, sets or [])
    except ConfigError as exc:
        raise _fail(str(exc)) from None


@app.command("crlb")
def crlb_cmd(
    config: Annotated[Path, typer.Argument(help="Scenario config (YAML).")],
    out_file: Annotated[Path, typer.Option("--out", help="CSV file to write.")],
    set_: SetOption = None,
    matching: Annotated[
        str | None, typer.Option(help="Override the matching scheme: attitude | attitude_rate.")
    ] = None,
) -> None:
    """Posterior Cramér–Rao bound per epoch (1-σ, display units) as CSV."""
    sets = list(set_ or [])
    if matching is not None:
        sets.append(f"filter.matching={matching}")
    cfg = _load(config, sets)
    from qkf.transfer_alignment.crlb import crlb
    from qkf.transfer_alignment.report import write_crlb_csv

    write_crlb_csv(out_file, crlb(cfg))
    out.print(f"wrote {out_file}")


@app.command("bench")
def bench_cmd(
    config: Annotated[Path, typer.Argument(help="Scenario config (YAML).")],
    methods: Annotated[
        str,
        typer.Option(help="Comma-separated methods, or 'all': kf, kf-tuned, sage-husa, qkf, mmae."),
    ] = "all",
    trials: Annotated[
        int | None, typer.Option(help="Monte Carlo trials (config: run.trials).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Seed (config: run.seed).")] = None,
    out_dir: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path(
        "results/bench"
    ),
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    backend: Annotated[
        str, typer.Option(help="local (processes on this machine) or ray (Ray tasks).")
    ] = "local",
    workers: Annotated[
        int | None, typer.Option(help="local backend: worker processes (config: run.workers).")
    ] = None,
) -> None:
    """Monte Carlo comparison of filters: rms.csv, summary.csv, summary.md, crlb.csv, plots."""
    from qkf.transfer_alignment.benchmark import parse_methods, run_benchmark
    from qkf.core.io import atomic_write_csv, slug
    from qkf.transfer_alignment.report import SUMMARY_COLUMNS, summary_rows, write_bench

    cfg = _load(config, set_)
    if trials is not None and trials < 1:
        raise _fail("--trials must be at least 1")
    if seed is not None and seed < 0:
        raise _fail("--seed must be non-negative")
    try:
        names = parse_methods(methods)
    except ValueError as exc:
        raise _fail(f"--methods: {exc}") from None
    if backend not in ("local", "ray"):
        raise _fail(f"--backend: {backend!r} is not local or ray")
    if workers is not None and workers < 1:
        raise _fail("--workers must be at least 1")

    if cfg.sweep is None:
        runs = [(None, cfg, out_dir)]
    else:
        runs = []
        for value in cfg.sweep.values:
            sub = _load(config, [*(set_ or []), f"{cfg.sweep.key}={value}"])
            leaf = cfg.sweep.key.split(".")[-1]
            runs.append((value, sub, out_dir / f"{leaf}={slug(value)}"))
    sweep_rows = []
    for value, run_cfg, run_out in runs:
        if value is not None:
            out.print(f"[bold]{cfg.sweep.key if cfg.sweep else ''} = {value}[/]")
        res = run_benchmark(
            run_cfg,
            names,
            trials=trials,
            seed=seed,
            progress=not quiet,
            backend=backend,
            workers=workers,
        )
        write_bench(res, run_out)
        sweep_rows += [[value, *row] for row in summary_rows(res)]
        # raw markdown, unwrapped: a narrow terminal must not truncate the numbers
        out.print(
            (run_out / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False
        )
        out.print(f"wrote {run_out}/")
    if cfg.sweep is not None:
        atomic_write_csv(
            out_dir / "sweep_summary.csv", (cfg.sweep.key, *SUMMARY_COLUMNS), sweep_rows
        )
        out.print(f"wrote {out_dir / 'sweep_summary.csv'}")


@app.command("study")
def study_cmd(
    study: Annotated[Path, typer.Argument(help="Study file (configs/studies/*.yaml).")],
    out_dir: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path(
        "results/study"
    ),
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Run the cases of a study and plot them together: case folders, study.csv, study.png."""
    from qkf.transfer_alignment.study import run_study

    try:
        written = run_study(study, out_dir, progress=not quiet)
    except ConfigError as exc:
        raise _fail(str(exc)) from None
    out.print(f"wrote {len(written)} files under {out_dir}/ (study.csv, study.png)")


@app.command("train")
def train_cmd(
    config: Annotated[Path, typer.Argument(help="Training config (configs/train_*.yaml).")],
    out_dir: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path(
        "results/train"
    ),
    seed: Annotated[int | None, typer.Option(help="Seed (config: seed).")] = None,
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Train the agent named in the config; saves model.zip / model.npz and config.yaml."""
    from agents.training import load_train_config, train

    sets = list(set_ or []) + ([f"seed={seed}"] if seed is not None else [])
    try:
        cfg = load_train_config(config, sets)
    except ConfigError as exc:
        raise _fail(str(exc)) from None
    path = train(cfg, out_dir, progress=not quiet)
    out.print(f"wrote {path}")


@app.command("evaluate")
def evaluate_cmd(
    model: Annotated[Path, typer.Argument(help="Saved agent: model.zip or model.npz.")],
    scenario: Annotated[
        str | None, typer.Option(help="Preset name or config path (default: the training one).")
    ] = None,
    trials: Annotated[int, typer.Option(help="Monte Carlo trials.")] = 20,
    seed: Annotated[int, typer.Option(help="Seed of the evaluation trials.")] = 12345,
    out_dir: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path(
        "results/evaluate"
    ),
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Filter Monte Carlo trials with the policy's κ; writes the SPEC §8 files."""
    from agents.training import Policy
    from envs.transfer_alignment import resolve_scenario
    from qkf.transfer_alignment.benchmark import run_benchmark
    from qkf.transfer_alignment.report import write_bench

    if not model.is_file():
        raise _fail(f"{model}: no such model file")
    if trials < 1:
        raise _fail("--trials must be at least 1")
    try:
        policy = Policy(model)
        cfg = resolve_scenario(scenario or policy.cfg.scenario, list(set_ or []))
    except ConfigError as exc:
        raise _fail(str(exc)) from None
    res = run_benchmark(cfg, [f"policy:{model}"], trials=trials, seed=seed, progress=not quiet)
    write_bench(res, out_dir)
    out.print((out_dir / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
