"""The command line: ``qkf crlb``, ``bench``, ``plot``, ``study``, ``train``, ``evaluate``
(transfer alignment), ``qkf gyros …`` (redundant gyros), ``qkf fuse`` (star camera +
angular accelerometer) and ``qkf align`` (sensor alignment).

This is the one module that sits above ``qkf``, ``envs`` and ``agents``: the library never
imports the other two; the commands that need them import them when they run (so ``torch`` is
loaded only by the commands that use an agent). Config arguments are preset names
(``thermal_snap``) or paths. Exit codes: 0 success, 2 bad input (config, option), 1 anything
else.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from qkf.alignment.cli import align_cmd
from qkf.core.cli_support import (
    OverwriteOption,
    SetOption,
    fail,
    out,
    out_dir,
    out_file,
    seed_option,
)
from qkf.core.config import ConfigError
from qkf.redundant_gyros.cli import app as gyros_app
from qkf.sca_fusion.cli import fuse_cmd
from qkf.transfer_alignment.config import MAX_TRIALS, Config, load_config

if TYPE_CHECKING:  # the zoo is imported by its commands only (torch stays unloaded)
    from agents.zoo import ZooEntry

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="qkf: adaptive Kalman filtering gym for in-orbit gyro calibration.",
)


def _show_version(value: bool) -> None:
    if value:
        from qkf import __version__

        out.print(f"qkf {__version__}", highlight=False)
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_show_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """qkf: adaptive Kalman filtering gym for in-orbit gyro calibration."""


ConfigArgument = Annotated[
    str, typer.Argument(help="Scenario: a preset name (paper) or a YAML path.")
]


def _load(config: str, sets: list[str] | None) -> Config:
    try:
        return load_config(config, sets or [])
    except ConfigError as exc:
        raise fail(str(exc)) from None


def _check_workload(cfg: Config, trials: int | None, source: object) -> None:
    """Refuse a run whose trials × epochs exceed the documented limits (before any work);
    ``source``: the config file or preset, named in the message."""
    from qkf.transfer_alignment.config import check_workload

    try:
        check_workload(cfg, trials)
    except ConfigError as exc:
        raise fail(f"{source}: {exc}") from None


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
    cfg = _load(config, sets)
    from qkf.transfer_alignment.crlb import crlb
    from qkf.transfer_alignment.report import write_crlb_csv
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
    methods: Annotated[
        str | None,
        typer.Option(
            help="Comma-separated method specs, or 'all' (default): kf, kf-tuned, sage-husa, qkf, "
            "mmae, imm, fading, vbakf, covariance-matching, batch; named only: oracle "
            "(truth-tuned reference), alarm-burst (NIS-alarm schedule); policy:PATH (a saved "
            "agent); package.module:function (your own); LABEL=SPEC."
        ),
    ] = None,
    trials: Annotated[
        int | None, typer.Option(help="Monte Carlo trials (config: run.trials).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Seed (config: run.seed).")] = None,
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")] = "results/bench",
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    backend: Annotated[
        str, typer.Option(help="local (processes on this machine) or ray (Ray tasks).")
    ] = "local",
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
) -> None:
    """Monte Carlo comparison of methods: rms.csv, summary.csv, summary.md, crlb.csv, plots,
    run.json. --out must be new, empty or (with --overwrite) an earlier bench run, which is
    replaced whole when the run has finished.

    A config with a ``sweep`` runs once per value into OUT/<key>=<value>/ and writes
    OUT/sweep_summary.csv.
    """
    from qkf.core.io import OutputError
    from qkf.core.montecarlo import BACKENDS
    from qkf.transfer_alignment.benchmark import parse_methods, run_benchmark
    from qkf.transfer_alignment.methods import MethodOutputError
    from qkf.transfer_alignment.report import write_bench
    from qkf.transfer_alignment.study import CaseRun, run_sweep, sweep_cases

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
    _check_workload(cfg, trials, config if config is not None else from_manifest)
    try:
        named = parse_methods("all" if methods is None else methods)
    except ValueError as exc:
        raise fail(f"--methods: {exc}") from None
    if backend not in BACKENDS:
        raise fail(f"--backend: {backend!r} is not {' or '.join(BACKENDS)}")
    if workers is not None and workers < 1:
        raise fail("--workers must be at least 1")
    if cfg.sweep is None:
        if resume:
            raise fail("--resume is for sweeps; a run replaces --out whole (--overwrite)")
        folder = out_dir(out_path, "bench", overwrite)
    else:
        folder = Path(out_path)  # the sweep's folder: checked by run_sweep (prepare_output)
    bench = {"progress": not quiet, "backend": backend, "workers": workers}

    def show(folder: Path) -> None:
        # raw markdown, unwrapped: a narrow terminal must not truncate the numbers
        text = (folder / "summary.md").read_text()
        out.print(text, soft_wrap=True, markup=False, highlight=False)
        out.print(f"wrote {folder}/")

    try:
        if cfg.sweep is None:
            res = run_benchmark(cfg, named, trials, seed, **bench)  # type: ignore[arg-type]
            write_bench(res, folder)
            show(folder)
            return
        key = cfg.sweep.key
        assert config is not None
        cases = sweep_cases(config, list(set_ or []), cfg)

        def on_case(case: CaseRun, folder: Path, reused: bool) -> None:
            out.print(f"[bold]{key} = {case.label}[/]" + (" (finished earlier)" if reused else ""))
            show(folder)

        summary = run_sweep(
            cases, key, named, folder, trials, seed, resume, overwrite, on_case, **bench
        )
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {summary}")


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

    from qkf.transfer_alignment.report import redraw_bench
    from qkf.transfer_alignment.study import redraw_study

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
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    resume: Annotated[
        bool, typer.Option(help="Finish an interrupted study in --out (finished cases kept).")
    ] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace an earlier study in --out.")] = False,
) -> None:
    """Run the cases of a study and plot them together: case folders, study.csv, study.png,
    run.json. With --resume, a case folder is kept only if it was run with the same config
    (--set included), methods, trials and seed."""
    from rich.markup import escape

    from qkf.core import presets
    from qkf.core.config import read_yaml_mapping
    from qkf.core.io import OutputError
    from qkf.transfer_alignment.config import check_workload
    from qkf.transfer_alignment.methods import MethodOutputError
    from qkf.transfer_alignment.study import CaseRun, load_study, prepare_output, run_study

    try:
        kind = read_yaml_mapping(presets.resolve(study, "studies"), "study").get("kind")
    except ConfigError as exc:
        raise fail(str(exc)) from None
    if kind == "claims":
        if trials is not None or set_:
            raise fail(
                "--trials and --set are not for a claims study: its trials and configs are "
                "part of each claim's evidence (edit a copy of the study file instead)"
            )
        _claims(study, out_path, quiet, overwrite)
        return
    if trials is not None and not 1 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 1 and {MAX_TRIALS:,}")
    try:
        spec, configs = load_study(study, list(set_ or []))
        if spec.kind == "crlb" and trials is not None:
            raise fail(f"--trials: {study} is a CRLB study; it runs no trials")
        for i, (case, cfg) in enumerate(zip(spec.cases, configs, strict=True)):
            if spec.kind == "bench":
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
            trials=trials, sets=list(set_ or []), on_start=on_start,
        )  # fmt: skip
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {len(written)} entries under {out_path}/ (study.csv, study.png, run.json)")


@app.command("train")
def train_cmd(
    config: Annotated[
        str, typer.Argument(help="Training config: a preset name (train_ppo) or a YAML path.")
    ],
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")] = "results/train",
    seed: Annotated[int | None, typer.Option(help="Seed (config: seed).")] = None,
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Go on from the newest checkpoint in --out although the config differs (only "
            "total_steps, episodes, eval.every_steps, torch_threads may).",
        ),
    ] = False,
    force_new: Annotated[
        bool,
        typer.Option(
            "--force-new", help="Discard the run in --out (model, checkpoints, logs); start over."
        ),
    ] = False,
) -> None:
    """Train the agent named in the config; saves model.zip / model.npz, config.yaml,
    training.json, checkpoints/, eval/, best/ and tb/.

    A rerun into the same --out with the same config goes on from the newest checkpoint; with
    another config it is refused (the differing fields are listed) unless --resume or
    --force-new.
    """
    if resume and force_new:
        raise fail("--resume and --force-new exclude each other")
    seed_option(seed)
    from agents.config import load_train_config, train_config_source
    from agents.training import plan_training, run_training

    sets = list(set_ or []) + ([f"seed={seed}"] if seed is not None else [])
    try:
        cfg = load_train_config(config, sets)
        plan = plan_training(
            cfg,
            out_path,
            resume=resume,
            force_new=force_new,
            source=train_config_source(config, sets),
        )
    except ConfigError as exc:
        raise fail(str(exc)) from None
    for note in plan.notes:
        out.print(note, soft_wrap=True, markup=False, highlight=False)
    if plan.complete:
        out.print(f"{plan.model_path} is up to date (--force-new retrains)")
        return
    try:
        path = run_training(plan, progress=not quiet)
    except ConfigError as exc:  # hyperparameter values the algorithm refuses; nothing written
        raise fail(str(exc)) from None
    out.print(f"wrote {path}")


@app.command("evaluate")
def evaluate_cmd(
    model: Annotated[Path, typer.Argument(help="Saved agent: model.zip or model.npz.")],
    scenario: Annotated[
        str | None, typer.Option(help="Preset name or config path (default: the training one).")
    ] = None,
    trials: Annotated[int, typer.Option(help="Monte Carlo trials.")] = 20,
    seed: Annotated[int, typer.Option(help="Seed of the evaluation trials.")] = 12345,
    out_path: Annotated[str, typer.Option("--out", help="Output directory.")] = "results/evaluate",
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    overwrite: OverwriteOption = False,
) -> None:
    """Filter Monte Carlo trials with the policy's κ; writes the files of ``qkf bench``."""
    from agents.policy import Policy
    from qkf.transfer_alignment.benchmark import parse_methods, run_benchmark
    from qkf.transfer_alignment.report import write_bench

    if model.is_dir():
        raise fail(f"{model}: is a directory, not a model file (model.zip or model.npz)")
    if not model.is_file():
        raise fail(f"{model}: no such model file")
    if not 1 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 1 and {MAX_TRIALS:,}")
    seed_option(seed)
    try:
        policy = Policy(model)
        cfg = load_config(scenario or policy.cfg.scenario, list(set_ or []))
        named = parse_methods(f"policy:{model}")
    except (ConfigError, ValueError) as exc:
        raise fail(str(exc)) from None
    _check_workload(cfg, trials, scenario or policy.cfg.scenario)
    folder = out_dir(out_path, "bench", overwrite)
    res = run_benchmark(cfg, named, trials=trials, seed=seed, progress=not quiet)
    write_bench(res, folder)
    out.print((folder / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)


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


zoo_app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="The zoo of trained policies (agents/zoo/<name>/): train, evaluate, promote, list.",
)


def _entry(name: str) -> ZooEntry:
    from agents.zoo import load_entry

    try:
        return load_entry(name)
    except ConfigError as exc:
        raise fail(str(exc)) from None


WorkOption = Annotated[
    str | None,
    typer.Option(
        "--work",
        help="Work folder (checkpoints, logs, bench outputs, judged card): results/zoo/NAME.",
    ),
]


def _work(work: str | None, entry: ZooEntry) -> Path:
    """The zoo command's work folder, checked before any work (exit 2). It is the command's own
    workspace: it writes only subfolders and files it names, each replaced only if it holds an
    earlier run of its own kind."""
    from qkf.core.io import OutputError, check_output_dir

    try:
        return check_output_dir(Path("results/zoo") / entry.name if work is None else work)
    except OutputError as exc:
        raise fail(f"--work: {exc}") from None


@zoo_app.command("list")
def zoo_list_cmd() -> None:
    """The zoo's entries, with their shipped seed and description."""
    from agents.zoo import list_entries

    for e in list_entries():
        chosen = e.selected_seed()
        shipped = f"seed {chosen}" if chosen is not None else "not trained"
        out.print(f"{e.name}: {shipped}; {e.spec.description}", soft_wrap=True, markup=False)


@zoo_app.command("train")
def zoo_train_cmd(
    name: Annotated[str, typer.Argument(help="Zoo entry (agents/zoo/NAME).")],
    seeds: Annotated[
        str | None, typer.Option(help="Comma-separated training seeds (default: zoo.yaml's).")
    ] = None,
    work: WorkOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Train every seed of the entry (a finished run is reused) and ship the best one."""
    from agents.zoo.commands import train_entry

    entry = _entry(name)
    chosen_seeds = None
    if seeds is not None:
        parts = [s.strip() for s in seeds.split(",")]
        if not any(parts):
            raise fail("--seeds: an empty list; give seeds such as 0,1,2 (or leave it out)")
        try:
            chosen_seeds = [int(s) for s in parts]
        except ValueError:
            raise fail(f"--seeds: {seeds!r} is not a comma-separated list of integers") from None
        if any(s < 0 for s in chosen_seeds):
            raise fail("--seeds: seeds must be non-negative")
        if len(set(chosen_seeds)) != len(chosen_seeds):
            raise fail(f"--seeds: {seeds!r} names a seed twice")
    folder = _work(work, entry)
    try:
        chosen = train_entry(entry, folder, chosen_seeds, not quiet, lambda m: out.print(m))
    except ConfigError as exc:
        raise fail(str(exc)) from None
    out.print(f"shipped seed {chosen}; wrote {entry.folder}/ (card.md)")


@zoo_app.command("evaluate")
def zoo_evaluate_cmd(
    name: Annotated[str, typer.Argument(help="Zoo entry (agents/zoo/NAME).")],
    trials: Annotated[
        int | None, typer.Option(help="Trials of every judging case (default: zoo.yaml's).")
    ] = None,
    work: WorkOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    update_entry: Annotated[
        bool,
        typer.Option(
            "--update-entry",
            help="Also rewrite the shipped entry's evaluation/ and card.md (agents/zoo/NAME).",
        ),
    ] = False,
) -> None:
    """Judge every trained seed against the baselines and the oracle on held-out benchmark
    seeds; writes evaluation/ and card.md into --work (and, with --update-entry, into the
    entry)."""
    from agents.zoo.commands import evaluate_entry

    entry = _entry(name)
    if trials is not None and not 2 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 2 and {MAX_TRIALS:,}")
    if not entry.trained_seeds():
        raise fail(f"{entry.folder}: no trained seed (run qkf zoo train {entry.name} first)")
    folder = _work(work, entry)
    try:
        card = evaluate_entry(
            entry, folder, trials, not quiet, lambda m: out.print(m), update_entry
        )
    except (ConfigError, FileNotFoundError) as exc:
        raise fail(str(exc)) from None
    out.print(card.read_text(), soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {card}" + (f" and {entry.folder}/card.md" if update_entry else ""))


@zoo_app.command("promote")
def zoo_promote_cmd(
    name: Annotated[str, typer.Argument(help="Zoo entry (agents/zoo/NAME).")],
) -> None:
    """Copy the entry's shipped policy and card to agents/zoo/best/."""
    from agents.zoo.commands import promote

    try:
        best = promote(_entry(name))
    except FileNotFoundError as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {best}/")


app.add_typer(zoo_app, name="zoo")


# The other estimation problems' commands (each package's cli module imports only typer and
# qkf.core at import time): a command group, and two top-level commands.
app.add_typer(gyros_app, name="gyros", help="Redundant skewed gyros: FDI and UKF calibration.")
app.command("fuse")(fuse_cmd)
app.command("align")(align_cmd)


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
