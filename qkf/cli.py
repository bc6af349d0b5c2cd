"""The command line: ``qkf crlb``, ``bench``, ``study``, ``train``, ``evaluate``.

This is the one module that sits above ``qkf``, ``envs`` and ``agents``: the library never
imports the other two; the commands that need them import them when they run (so ``torch`` is
loaded only by the commands that use an agent). Config arguments are preset names
(``thermal_snap``) or paths. Exit codes: 0 success, 2 bad input (config, option), 1 anything
else.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import Config, load_config

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
    # soft_wrap: a message must not be broken at the terminal width (file paths, fields)
    err.print(f"[bold red]error:[/] {escape(msg)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)


ConfigArgument = Annotated[
    str, typer.Argument(help="Scenario: a preset name (paper) or a YAML path.")
]


def _load(config: str, sets: list[str] | None) -> Config:
    try:
        return load_config(config, sets or [])
    except ConfigError as exc:
        raise _fail(str(exc)) from None


@app.command("crlb")
def crlb_cmd(
    config: ConfigArgument,
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
    config: ConfigArgument,
    methods: Annotated[
        str,
        typer.Option(
            help="Comma-separated method specs, or 'all': kf, kf-tuned, sage-husa, qkf, mmae; "
            "policy:PATH (a saved agent); package.module:function (your own); LABEL=SPEC."
        ),
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
    """Monte Carlo comparison of methods: rms.csv, summary.csv, summary.md, crlb.csv, plots.

    A config with a ``sweep`` runs once per value into OUT/<key>=<value>/ and writes
    OUT/sweep_summary.csv.
    """
    from qkf.core.montecarlo import BACKENDS
    from qkf.transfer_alignment.benchmark import parse_methods, run_benchmark
    from qkf.transfer_alignment.methods import MethodOutputError
    from qkf.transfer_alignment.report import write_bench
    from qkf.transfer_alignment.study import CaseRun, run_sweep, sweep_cases

    cfg = _load(config, set_)
    if trials is not None and trials < 1:
        raise _fail("--trials must be at least 1")
    if seed is not None and seed < 0:
        raise _fail("--seed must be non-negative")
    try:
        named = parse_methods(methods)
    except ValueError as exc:
        raise _fail(f"--methods: {exc}") from None
    if backend not in BACKENDS:
        raise _fail(f"--backend: {backend!r} is not {' or '.join(BACKENDS)}")
    if workers is not None and workers < 1:
        raise _fail("--workers must be at least 1")
    bench = {
        "trials": trials,
        "seed": seed,
        "progress": not quiet,
        "backend": backend,
        "workers": workers,
    }

    def show(folder: Path) -> None:
        # raw markdown, unwrapped: a narrow terminal must not truncate the numbers
        out.print(
            (folder / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False
        )
        out.print(f"wrote {folder}/")

    try:
        if cfg.sweep is None:
            write_bench(run_benchmark(cfg, named, **bench), out_dir)  # type: ignore[arg-type]
            show(out_dir)
            return
        key = cfg.sweep.key
        cases = sweep_cases(config, list(set_ or []), cfg)

        def on_case(case: CaseRun, folder: Path) -> None:
            out.print(f"[bold]{key} = {case.label}[/]")
            show(folder)

        summary = run_sweep(cases, key, named, out_dir, on_case=on_case, **bench)  # type: ignore[arg-type]
    except (ConfigError, MethodOutputError) as exc:
        raise _fail(str(exc)) from None
    out.print(f"wrote {summary}")


@app.command("study")
def study_cmd(
    study: Annotated[str, typer.Argument(help="Study: a preset name (matching) or a YAML path.")],
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
    config: Annotated[
        str, typer.Argument(help="Training config: a preset name (train_ppo) or a YAML path.")
    ],
    out_dir: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path(
        "results/train"
    ),
    seed: Annotated[int | None, typer.Option(help="Seed (config: seed).")] = None,
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Train the agent named in the config; saves model.zip / model.npz and config.yaml."""
    from agents.config import load_train_config
    from agents.training import train

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
    """Filter Monte Carlo trials with the policy's κ; writes the files of ``qkf bench``."""
    from agents.policy import Policy
    from qkf.transfer_alignment.benchmark import run_benchmark
    from qkf.transfer_alignment.report import write_bench

    if not model.is_file():
        raise _fail(f"{model}: no such model file")
    if trials < 1:
        raise _fail("--trials must be at least 1")
    try:
        policy = Policy(model)
        cfg = load_config(scenario or policy.cfg.scenario, list(set_ or []))
    except ConfigError as exc:
        raise _fail(str(exc)) from None
    res = run_benchmark(cfg, [f"policy:{model}"], trials=trials, seed=seed, progress=not quiet)
    write_bench(res, out_dir)
    out.print((out_dir / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
