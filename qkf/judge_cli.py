"""``qkf judge PROBLEM``: methods and policies compared on a problem's scenario families, for any
registered problem (:mod:`qkf.core.family_judging`; docs/methods.md, "Judging on
families")."""

from __future__ import annotations

from typing import Annotated

import typer

from qkf.core.cli_support import NoCacheOption, out, out_dir, refused

app = typer.Typer(no_args_is_help=True)


def _names(raw: str | None) -> list[str] | None:
    return None if raw is None else [s.strip() for s in raw.split(",") if s.strip()]


@app.command()
def judge(
    problem: Annotated[
        str, typer.Argument(help="A registered problem: transfer_alignment, redundant_gyros, …")
    ],
    methods: Annotated[
        str,
        typer.Option(
            help="Method specs, comma-separated: NAME, LABEL=NAME, policy:PATH (the problem's)."
        ),
    ],
    out_path: Annotated[str, typer.Option("--out", help="Output folder.")],
    families: Annotated[
        str | None, typer.Option(help="Families (comma-separated; default: all of the problem).")
    ] = None,
    focus: Annotated[
        str | None,
        typer.Option(help="Labels compared with every other method (default: every method)."),
    ] = None,
    trials: Annotated[int, typer.Option(help="Trials per family.")] = 64,
    seed: Annotated[
        int | None, typer.Option(help="Benchmark seed (default: the problem's first judging one).")
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="dotted.key=value override of every family's config."),
    ] = None,
    level: Annotated[float, typer.Option(help="Bootstrap interval level.")] = 0.95,
    resamples: Annotated[int, typer.Option(help="Bootstrap resamples.")] = 2000,
    overwrite: Annotated[bool, typer.Option(help="Replace an earlier judging run.")] = False,
    progress: Annotated[bool, typer.Option(help="Progress bars.")] = True,
    no_cache: NoCacheOption = False,
) -> None:
    """Run every method on the same trials of each family and compare each focus method with
    every other: pooled RMS ratio and median per-trial ratio with paired bootstrap intervals,
    P(improve), worst decile, verdict. Writes trials.csv, versus.csv, versus.md and run.json.
    Results of the methods are read from and stored in the results cache (docs/caching.md);
    run.json counts the hits and misses per family and method."""
    from qkf.core.family_judging import (
        RUN_KIND,
        judge_rows,
        plan_judging,
        run_judging,
        write_judging,
    )
    from qkf.core.results_cache import CacheLog

    folder = out_dir(out_path, RUN_KIND, overwrite)
    with refused():
        plan = plan_judging(
            problem, _names(families), _names(methods) or [], _names(focus), trials, seed,
            list(set_ or []), level, resamples,
        )  # fmt: skip

    def on_family(i: int, n: int, family: str) -> None:
        out.print(f"family {i}/{n}: {family}", highlight=False)

    cache: dict[str, CacheLog] | None = None if no_cache else {}
    errors = run_judging(plan, progress, on_family, cache)
    rows = judge_rows(plan, errors)
    write_judging(plan, errors, rows, folder, cache)
    damaged = [p for log in (cache or {}).values() for p in log.problems]
    if damaged:
        out.print(f"{len(damaged)} damaged results-cache entries recomputed (run.json)")
    out.print(f"wrote {folder}/versus.md, versus.csv, trials.csv", highlight=False)
