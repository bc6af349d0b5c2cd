"""``qkf crlb``, ``bench``, ``plot`` and ``study``: the transfer-alignment commands
(docs/architecture.md, "Problem shape"). A Typer app mounted by :mod:`qkf.cli`; heavy imports
happen inside the commands.

Exit codes as everywhere: 0 success, 2 bad input (config, option: one message naming the file
and the field; nothing written), 1 anything else; ``bench`` also 3: a method diverged (every
file is written, and summary.md and the terminal name the method, trial or file, and epoch).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from qkf.core.cli_support import (
    BackendOption,
    NoCacheOption,
    OverwriteOption,
    SetOption,
    backend_options,
    err,
    fail,
    out,
    out_dir,
    out_file,
    refused,
    seed_option,
)
from qkf.core.config import ConfigError
from qkf.transfer_alignment.config import (
    MAX_TRIALS,
    STUDIES,
    Config,
    check_workload,
    load_config,
    load_scenario,
)

if TYPE_CHECKING:
    from qkf.transfer_alignment.divergence import Divergence

app = typer.Typer(add_completion=False, help="Transfer alignment: CRLB, benchmark, studies, plots.")

ConfigArgument = Annotated[
    str, typer.Argument(help="Scenario: a preset name (paper) or a YAML path.")
]


def _load(config: str, sets: list[str] | None) -> Config:
    try:
        return load_config(config, sets or [])
    except ConfigError as exc:
        raise fail(str(exc)) from None


MATCHING = ("attitude", "attitude_rate")


@app.command("crlb")
def crlb_cmd(
    config: ConfigArgument,
    out_path: Annotated[str, typer.Option("--out", help="CSV file to write.")],
    set_: SetOption = None,
    matching: Annotated[
        str | None, typer.Option(help="Override the matching scheme: attitude | attitude_rate.")
    ] = None,
) -> None:
    """Posterior Cramér–Rao bound per epoch (1-σ, display units) as CSV."""
    if matching is not None and matching not in MATCHING:
        raise fail(f"--matching: {matching!r} is not {' or '.join(MATCHING)}")
    sets = list(set_ or [])
    if matching is not None:
        sets.append(f"filter.matching={matching}")
    with refused():  # no method runs: a user section under adaptive is an unknown key
        cfg = load_scenario(config, sets)
    from qkf.transfer_alignment.crlb import crlb
    from qkf.transfer_alignment.results import write_crlb_csv
    from qkf.transfer_alignment.states import STATE_COLUMNS

    path = out_file(out_path, ",".join(("t_s", *STATE_COLUMNS)))

    write_crlb_csv(path, crlb(cfg))
    out.print(f"wrote {path}")


@app.command("bench")
def bench_cmd(
    config: Annotated[
        str | None,
        typer.Argument(help="Scenario: a preset name (paper) or a YAML path."),
    ] = None,
    # A literal, not built from the registry: importing qkf.transfer_alignment.methods when the
    # CLI starts loads numba and the filter (measured: `import qkf.cli` 0.2 s → 0.7 s, for every
    # command, --help included). tests/test_words.py checks it against METHODS, BUILTIN_METHODS and
    # METHOD_FACTORIES: keep the shape "'all' (default): …; named only: …; …".
    methods: Annotated[
        str | None,
        typer.Option(
            help="Comma-separated method specs, or 'all' (default): kf, kf-tuned, sage-husa, qkf, "
            "mmae, imm, fading, vbakf, covariance-matching, batch; named only: oracle "
            "(truth-tuned reference), alarm-burst (NIS-alarm schedule), glr (CUSUM reset), "
            "clock (best open-loop schedule), hindsight (per-trial best schedule), "
            "vbakf-tuned, imm-tuned, sage-husa-tuned, covariance-matching-tuned, fading-tuned, "
            "alarm-burst-tuned, glr-tuned, nis-rule-tuned (Optuna-tuned), nis-rule (NIS "
            "burst rule), "
            "kf-tuned-mixed, clock-mixed, alarm-burst-mixed, vbakf-tuned-mixed, "
            "imm-tuned-mixed, sage-husa-tuned-mixed, covariance-matching-tuned-mixed, "
            "fading-tuned-mixed, alarm-burst-tuned-mixed, glr-tuned-mixed, "
            "nis-rule-tuned-mixed (tuned on the training mixture); policy:PATH (a saved "
            "agent); hindsight-moves:CONTROLS (per-trial best schedule of v4's moves); "
            "package.module:function (your own); LABEL=SPEC."
        ),
    ] = None,
    trials: Annotated[
        int | None, typer.Option(help="Monte Carlo trials (config: run.trials).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Seed (config: run.seed).")] = None,
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")] = "results/bench",
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    backend: BackendOption = "local",
    workers: Annotated[
        int | None, typer.Option(help="local backend: worker processes (config: run.workers).")
    ] = None,
    from_manifest: Annotated[
        Path | None,
        typer.Option(help="Rerun the run described by a run.json (config, methods, trials, seed)."),
    ] = None,
    resume: Annotated[
        bool, typer.Option(help="Sweeps: finish an interrupted sweep in --out.")
    ] = False,
    overwrite: OverwriteOption = False,
    data: Annotated[
        list[Path] | None,
        typer.Option(
            "--data",
            help="Recorded runs (CSV or Parquet, or a folder of them; repeat for several) "
            "instead of simulated trials: each file is a trial. CONFIG gives the noise, prior "
            "and filter settings. See docs/recorded_data.md.",
        ),
    ] = None,
    ignore_column: Annotated[
        list[str] | None,
        typer.Option(
            "--ignore-column",
            help="With --data: an extra column of the files to read past (repeat for several; "
            "config: recorded.ignore_columns).",
        ),
    ] = None,
    no_cache: NoCacheOption = False,
) -> None:
    """Monte Carlo comparison of methods: rms.csv, summary.csv, summary.md, crlb.csv, plots,
    run.json. --out must be new, empty or (with --overwrite) an earlier bench run, which is
    replaced whole when the run has finished.

    A config with a ``sweep`` runs once per value into OUT/<key>=<value>/ and writes
    OUT/sweep_summary.csv.

    With --data the trials are recorded runs: estimates.csv (every method's estimates and σ per
    row), quality.csv and summary.md (NIS bands and whiteness, no truth needed), final.csv,
    estimates.png, nis.png; with truth columns in the files, everything above as well.
    """
    if data:
        if config is None or from_manifest is not None:
            raise fail("--data needs a CONFIG (noise, prior, filter settings), not --from-manifest")
        if trials is not None or resume or backend != "local" or (workers or 1) > 1:
            raise fail(
                "--data: the files are the trials (no --trials), run in this process "
                "(no --backend, --workers or --resume)"
            )
        _bench_recorded(
            config, set_, methods, seed, data, out_path, quiet, overwrite, ignore_column or []
        )
        return
    if ignore_column:
        raise fail("--ignore-column is for the files of --data")
    from qkf.core.io import OutputError
    from qkf.transfer_alignment.benchmark import parse_methods, refuse_tuning_seed, run_benchmark
    from qkf.transfer_alignment.campaigns import run_sweep, sweep_cases
    from qkf.transfer_alignment.cases import CaseRun
    from qkf.transfer_alignment.divergence import DIVERGED_HEADING, EXIT_DIVERGED
    from qkf.transfer_alignment.methods import MethodOutputError, resolve_method_settings
    from qkf.transfer_alignment.results import write_bench

    if (config is None) == (from_manifest is None):
        raise fail("give a CONFIG or --from-manifest run.json (not both)")
    if from_manifest is not None:
        if set_ or methods is not None or trials is not None or seed is not None:
            raise fail("--from-manifest takes the config, methods, trials and seed from it")
        cfg, methods, trials, seed = _from_manifest(from_manifest)
    else:
        assert config is not None
        cfg = _load(config, set_)
    if trials is not None and not 1 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 1 and {MAX_TRIALS:,}")
    seed_option(seed)
    with refused(f"{config if config is not None else from_manifest}: "):
        check_workload(cfg, trials)
    try:
        named = parse_methods("all" if methods is None else methods)
    except ValueError as exc:
        raise fail(f"--methods: {exc}") from None
    source = str(config if config is not None else from_manifest)
    try:  # the methods' settings sections, the file named, before any work
        cfg = resolve_method_settings(cfg, named, source)
        refuse_tuning_seed(named, cfg.run.seed if seed is None else seed)
        cases = (
            None
            if cfg.sweep is None or config is None
            else [
                replace(c, cfg=resolve_method_settings(c.cfg, named, f"{source} ({c.label})"))
                for c in sweep_cases(config, list(set_ or []), cfg)
            ]
        )
    except ConfigError as exc:
        raise fail(str(exc)) from None
    except ValueError as exc:  # a method's malformed settings declaration
        raise fail(f"--methods: {exc}") from None
    backend_options(backend, workers)
    if cfg.sweep is None:
        if resume:
            raise fail("--resume is for sweeps; a run replaces --out whole (--overwrite)")
        folder = out_dir(out_path, "bench", overwrite)
    else:
        folder = Path(out_path)  # the sweep's folder: checked by run_sweep (prepare_output)
    bench = {"progress": not quiet, "backend": backend, "workers": workers, "cache": not no_cache}

    diverged_cases: list[Path] = []

    def show(folder: Path) -> None:
        # raw markdown, unwrapped: a narrow terminal must not truncate the numbers
        text = (folder / "summary.md").read_text()
        out.print(text, soft_wrap=True, markup=False, highlight=False)
        out.print(f"wrote {folder}/")
        if f"\n{DIVERGED_HEADING}\n" in text:  # a sweep case (finished now or earlier)
            diverged_cases.append(folder)

    try:
        if cfg.sweep is None:
            res = run_benchmark(cfg, named, trials, seed, **bench)  # type: ignore[arg-type]
            write_bench(res, folder)
            show(folder)
            _exit_if_diverged([d for m in res.methods for d in m.divergences])
            return
        key = cfg.sweep.key
        assert cases is not None

        def on_case(case: CaseRun, folder: Path, reused: bool) -> None:
            out.print(f"[bold]{key} = {case.label}[/]" + (" (finished earlier)" if reused else ""))
            show(folder)

        summary = run_sweep(
            cases, key, named, folder, trials, seed, resume, overwrite, on_case, **bench
        )
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {summary}")
    if diverged_cases:
        for folder in diverged_cases:
            err.print(
                f"[bold red]diverged:[/] {escape(str(folder / 'summary.md'))}", soft_wrap=True
            )
        raise typer.Exit(EXIT_DIVERGED)


def _bench_recorded(
    config: str,
    sets: list[str] | None,
    methods: str | None,
    seed: int | None,
    data: list[Path],
    out_path: str,
    quiet: bool,
    overwrite: bool,
    ignore_columns: list[str],
) -> None:
    """``qkf bench CONFIG --data FILE …``: every check (config, methods, data, output folder)
    before any method runs; nothing is written on bad input."""
    from qkf.core.io import OutputError
    from qkf.transfer_alignment.benchmark import parse_methods, refuse_tuning_seed
    from qkf.transfer_alignment.methods import MethodOutputError, resolve_method_settings
    from qkf.transfer_alignment.recorded.grid import load_recorded
    from qkf.transfer_alignment.recorded.outputs import RECORDED_KIND, write_recorded_run
    from qkf.transfer_alignment.recorded.run import refuse_unjudgeable, run_recorded

    cfg = _load(config, sets)
    if cfg.sweep is not None:
        raise fail(f"{config}: sweep: a sweep runs simulated trials; drop it to use --data")
    seed_option(seed)
    if seed is not None:
        cfg = cfg.model_copy(update={"run": cfg.run.model_copy(update={"seed": seed})})
    if ignore_columns:
        extra = (*cfg.recorded.ignore_columns, *(c.strip() for c in ignore_columns))
        rc = cfg.recorded.model_copy(update={"ignore_columns": extra})
        cfg = cfg.model_copy(update={"recorded": rc})
    try:
        named = parse_methods("all" if methods is None else methods)
    except ValueError as exc:
        raise fail(f"--methods: {exc}") from None
    try:
        cfg = resolve_method_settings(cfg, named, config)
        refuse_tuning_seed(named, cfg.run.seed)
        rec = load_recorded(cfg, data)
        refuse_unjudgeable(rec)
    except ConfigError as exc:
        raise fail(str(exc)) from None
    except ValueError as exc:
        raise fail(f"--methods: {exc}") from None
    folder = out_dir(out_path, "bench" if rec.has_truth else RECORDED_KIND, overwrite)
    try:
        res = run_recorded(rec, named, progress=not quiet)
        write_recorded_run(res, folder)
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    text = (folder / "summary.md").read_text()
    out.print(text, soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {folder}/")
    _exit_if_diverged(res.divergences, res.file_names)


def _exit_if_diverged(divs: list[Divergence], names: list[str] | None = None) -> None:
    """Name every divergence on stderr and exit 3 (docs/recorded_data.md, "Divergence")."""
    from qkf.transfer_alignment.divergence import EXIT_DIVERGED

    if not divs:
        return
    for d in divs:
        text = d.describe(None if names is None else names[d.trial])
        err.print(
            f"[bold red]diverged:[/] {escape(text)}",
            highlight=False,
            soft_wrap=True,
        )
    raise typer.Exit(EXIT_DIVERGED)


@app.command("record")
def record_cmd(
    config: ConfigArgument,
    out_path: Annotated[Path, typer.Option("--out", help="The file to write (.csv or .parquet).")],
    trial: Annotated[int, typer.Option(help="Which trial of the run (0-based).")] = 0,
    seed: Annotated[int | None, typer.Option(help="Seed (config: run.seed).")] = None,
    truth: Annotated[
        bool, typer.Option(help="Write the truth columns too (true_q*, true_bias_*, true_p_*).")
    ] = True,
    set_: SetOption = None,
) -> None:
    """Write one simulated trial as a recorded run (the --data format of qkf bench): the ADS
    attitude and rate, the gyro output and (--truth) the truth, one row per epoch."""
    from qkf.transfer_alignment.recorded.writer import simulate_to_file

    cfg = _load(config, set_)
    seed_option(seed)
    if not 0 <= trial < MAX_TRIALS:
        raise fail(f"--trial must be between 0 and {MAX_TRIALS - 1:,}")
    if out_path.exists():
        raise fail(f"--out: {out_path} exists; qkf record never overwrites a file")
    if out_path.suffix.lower() not in (".csv", ".parquet", ".pq"):
        raise fail(f"--out: {out_path}: give a .csv or .parquet file")
    try:
        simulate_to_file(cfg, cfg.run.seed if seed is None else seed, trial, out_path, truth=truth)
    except (ConfigError, OSError) as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {out_path}")


def _from_manifest(path: Path) -> tuple[Config, str, int, int]:
    from qkf.core.config import validate
    from qkf.core.manifest import read_manifest

    try:
        info = read_manifest(path, "bench")
        cfg = validate(Config, info["config"], f"{path}: config")
        specs = [m.get("spec") for m in info.get("methods", [])]
        if not specs or any(not isinstance(sp, str) for sp in specs):
            raise ConfigError(f"{path}: methods: a method was passed as an object, not a spec")
        return cfg, ",".join(specs), int(info["trials"]), int(info["seed"])
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise fail(str(exc)) from None
        raise fail(f"{path}: not a usable manifest ({exc!r})") from None


@app.command("plot")
def plot_cmd(
    folder: Annotated[
        Path, typer.Argument(help="A finished qkf bench folder, or a sweep's or a study's.")
    ],
) -> None:
    """Redraw every figure of a finished run from its CSV files and run.json (a study: each
    case's figures and study.png); nothing is rerun."""
    import os
    import tempfile

    from qkf.transfer_alignment.campaigns import redraw_study
    from qkf.transfer_alignment.results import redraw_bench

    if folder.is_file():
        raise fail(f"{folder}: is a file, not a results folder")
    if not folder.is_dir():
        raise fail(f"{folder}: no such folder")
    study = (folder / "study.csv").is_file()
    targets = (
        [folder]
        if (folder / "rms.csv").is_file()
        else sorted(p.parent for p in folder.glob("*/rms.csv"))
    )
    if not targets and not study:
        raise fail(f"{folder}: no qkf bench results (rms.csv) here or one level below")
    # every folder a figure goes into must take a new file, checked before reading anything
    # (a probe file, created and removed: permission bits say nothing for root or a read-only
    # mount)
    for target in dict.fromkeys([folder, *targets]):
        try:
            fd, probe = tempfile.mkstemp(prefix=".qkf-probe.", dir=target)
            os.close(fd)
            os.unlink(probe)
        except OSError:
            raise fail(f"{folder}: no permission to write in {target}") from None
    try:
        if study:
            written = redraw_study(folder)
        else:
            written = redraw_bench(*targets)
    except ConfigError as exc:
        raise fail(str(exc)) from None
    for path in written:
        out.print(f"wrote {path}")


@app.command("study")
def study_cmd(
    study: Annotated[str, typer.Argument(help="Study: a preset name (matching) or a YAML path.")],
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")] = "results/study",
    trials: Annotated[
        int | None, typer.Option(help="Monte Carlo trials of every case (study: trials).")
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Override a config value of every case, after the case's own: "
            "dotted.key=value (YAML value).",
        ),
    ] = None,
    families: Annotated[
        str | None,
        typer.Option(help="A families study: run only these families (comma-separated)."),
    ] = None,
    methods: Annotated[
        str | None,
        typer.Option(
            help="Methods added to the study's (comma-separated specs, e.g. "
            "best=policy:agents/zoo/best/model.zip; NAME#SEED=... per training seed)."
        ),
    ] = None,
    baselines: Annotated[
        str | None,
        typer.Option(
            help="Run only these of the study's methods (comma-separated labels, e.g. "
            "kf-tuned,glr); --methods are added to them."
        ),
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Judging seed (replaces study: seed).")] = None,
    shift: Annotated[
        bool,
        typer.Option(
            help="A families study: also judge its shift group (shift_families; nothing tunes "
            "on them, so each tuned baseline runs as its -mixed variant)."
        ),
    ] = False,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    resume: Annotated[
        bool, typer.Option(help="Finish an interrupted study in --out (finished cases kept).")
    ] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace an earlier study in --out.")] = False,
    no_cache: NoCacheOption = False,
    backend: BackendOption = "local",
    workers: Annotated[
        int | None,
        typer.Option(
            help="local backend: worker processes for the trials and the methods' tunings "
            "(config: run.workers)."
        ),
    ] = None,
) -> None:
    """Run the cases of a study and plot them together: case folders, study.csv, study.png,
    run.json. A families study (qkf study families) writes families.csv, families.md and
    families.png instead of study.png. With --resume, a case folder is kept only if it was run
    with the same config (--set included), methods, trials and seed."""
    from rich.markup import escape

    from qkf.core import presets
    from qkf.core.config import read_yaml_mapping
    from qkf.core.io import OutputError
    from qkf.transfer_alignment.campaigns import run_study
    from qkf.transfer_alignment.cases import CaseRun, prepare_output
    from qkf.transfer_alignment.config import check_workload
    from qkf.transfer_alignment.methods import MethodOutputError
    from qkf.transfer_alignment.study import load_study, study_cases

    try:
        unknown = presets.missing(study, STUDIES, "study")
        if unknown is not None:
            raise unknown
        kind = read_yaml_mapping(presets.resolve(study, STUDIES), "study").get("kind")
    except ConfigError as exc:
        raise fail(str(exc)) from None
    if kind == "claims":
        if families is not None or methods is not None or seed is not None or baselines or shift:
            raise fail(
                "--families, --shift, --methods, --baselines and --seed are not for a claims study"
            )
        if trials is not None or set_:
            raise fail(
                "--trials and --set are not for a claims study: its trials and configs are "
                "part of each claim's evidence (edit a copy of the study file instead)"
            )
        _claims(study, out_path, quiet, overwrite)
        return
    if trials is not None and not 1 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 1 and {MAX_TRIALS:,}")
    if seed is not None and not 0 <= seed < 2**63:
        raise fail("--seed must be between 0 and 2**63 - 1")
    chosen = None if families is None else [f.strip() for f in families.split(",") if f.strip()]
    added = None if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
    if methods is not None and not added:
        raise fail("--methods: no method given")
    kept = None if baselines is None else [b.strip() for b in baselines.split(",") if b.strip()]
    backend_options(backend, workers)
    try:
        spec, configs = load_study(
            study, list(set_ or []), families=chosen, methods=added, seed=seed, baselines=kept,
            shift=shift,
        )  # fmt: skip
        if spec.kind == "crlb" and trials is not None:
            raise fail(f"--trials: {study} is a CRLB study; it runs no trials")
        for i, (case, cfg) in enumerate(zip(study_cases(spec), configs, strict=True)):
            if spec.kind != "crlb":
                try:
                    check_workload(cfg, spec.trials if trials is None else trials)
                except ConfigError as exc:
                    raise ConfigError(f"{study}: cases.{i} ({case.label}): {exc}") from None
        prepare_output(out_path, resume, overwrite)
    except (ConfigError, OutputError) as exc:
        raise fail(str(exc)) from None

    def on_start(i: int, n: int, case: CaseRun) -> None:
        out.print(f"[bold]case {i}/{n}:[/] {escape(case.label)}", highlight=False)

    def on_case(case: CaseRun, folder: Path, reused: bool) -> None:
        out.print(
            f"{escape(case.label)}: {'finished earlier, kept' if reused else 'done'} "
            f"({escape(str(folder))}/)",
            highlight=False,
        )

    try:
        written = run_study(
            study, out_path, not quiet, resume, overwrite, on_case,
            trials=trials, sets=list(set_ or []), on_start=on_start, families=chosen,
            extra_methods=added, seed=seed, cache=not no_cache, baselines=kept,
            backend=backend, workers=workers, shift=shift,
        )  # fmt: skip
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    what = "families.csv, families.md, families.png" if spec.kind == "families" else "study.png"
    out.print(f"wrote {len(written)} entries under {out_path}/ (study.csv, {what}, run.json)")


def _claims(study: str, out_path: str | Path, quiet: bool, overwrite: bool = False) -> None:
    from qkf.core.io import OutputError
    from qkf.transfer_alignment.claims import load_claims, run_claims
    from qkf.transfer_alignment.methods import MethodOutputError

    try:
        load_claims(study)
    except ConfigError as exc:
        raise fail(str(exc)) from None
    folder = out_dir(out_path, "claims", overwrite)
    try:
        run_claims(study, folder, progress=not quiet)
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    text = (folder / "claims.md").read_text()
    out.print(text, soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {folder}/ (claims.csv, claims.md, one benchmark folder per config)")
