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
from qkf.core.cli_support import SetOption, check_out, fail, out
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
    out_file: Annotated[Path, typer.Option("--out", help="CSV file to write.")],
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
    check_out(out_file, "file")
    from qkf.transfer_alignment.crlb import crlb
    from qkf.transfer_alignment.report import write_crlb_csv

    write_crlb_csv(out_file, crlb(cfg))
    out.print(f"wrote {out_file}")


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
            "mmae, imm, fading, vbakf, covariance-matching, batch; oracle (truth-tuned reference); "
            "policy:PATH (a saved agent); package.module:function (your own); LABEL=SPEC."
        ),
    ] = None,
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
    from_manifest: Annotated[
        Path | None,
        typer.Option(help="Rerun the run described by a run.json (config, methods, trials, seed)."),
    ] = None,
    resume: Annotated[
        bool, typer.Option(help="Sweeps: finish an interrupted sweep in --out.")
    ] = False,
    overwrite: Annotated[
        bool, typer.Option(help="Sweeps: replace an earlier sweep in --out.")
    ] = False,
) -> None:
    """Monte Carlo comparison of methods: rms.csv, summary.csv, summary.md, crlb.csv, plots,
    run.json. --out is replaced whole when the run has finished.

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
    if seed is not None and not 0 <= seed < 2**63:
        raise fail("--seed must be between 0 and 2**63 - 1")
    try:
        named = parse_methods(methods or "all")
    except ValueError as exc:
        raise fail(f"--methods: {exc}") from None
    if backend not in BACKENDS:
        raise fail(f"--backend: {backend!r} is not {' or '.join(BACKENDS)}")
    if workers is not None and workers < 1:
        raise fail("--workers must be at least 1")
    check_out(out_dir)
    bench = {"progress": not quiet, "backend": backend, "workers": workers}

    def show(folder: Path) -> None:
        # raw markdown, unwrapped: a narrow terminal must not truncate the numbers
        text = (folder / "summary.md").read_text()
        out.print(text, soft_wrap=True, markup=False, highlight=False)
        out.print(f"wrote {folder}/")

    try:
        if cfg.sweep is None:
            if resume or overwrite:
                raise fail("--resume and --overwrite are for sweeps; a run replaces --out whole")
            res = run_benchmark(cfg, named, trials, seed, **bench)  # type: ignore[arg-type]
            write_bench(res, out_dir)
            show(out_dir)
            return
        key = cfg.sweep.key
        assert config is not None
        cases = sweep_cases(config, list(set_ or []), cfg)

        def on_case(case: CaseRun, folder: Path, reused: bool) -> None:
            out.print(f"[bold]{key} = {case.label}[/]" + (" (finished earlier)" if reused else ""))
            show(folder)

        summary = run_sweep(
            cases, key, named, out_dir, trials, seed, resume, overwrite, on_case, **bench
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
    folder: Annotated[Path, typer.Argument(help="A finished qkf bench folder (or a sweep's).")],
) -> None:
    """Redraw every figure of a finished run from its CSV files and run.json."""
    from qkf.transfer_alignment.report import redraw_bench

    if not folder.is_dir():
        raise fail(f"{folder}: no such folder")
    targets = (
        [folder]
        if (folder / "rms.csv").is_file()
        else sorted(p.parent for p in folder.glob("*/rms.csv"))
    )
    if not targets:
        raise fail(f"{folder}: no qkf bench results (rms.csv) here or one level below")
    try:
        for target in targets:
            for path in redraw_bench(target):
                out.print(f"wrote {path}")
    except ConfigError as exc:
        raise fail(str(exc)) from None


@app.command("study")
def study_cmd(
    study: Annotated[str, typer.Argument(help="Study: a preset name (matching) or a YAML path.")],
    out_dir: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path(
        "results/study"
    ),
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
    resume: Annotated[
        bool, typer.Option(help="Finish an interrupted study in --out (finished cases kept).")
    ] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace an earlier study in --out.")] = False,
) -> None:
    """Run the cases of a study and plot them together: case folders, study.csv, study.png."""
    from qkf.core import presets
    from qkf.core.config import read_yaml_mapping
    from qkf.core.io import OutputError
    from qkf.transfer_alignment.methods import MethodOutputError
    from qkf.transfer_alignment.study import CaseRun, load_study, prepare_output, run_study

    try:
        kind = read_yaml_mapping(presets.resolve(study, "studies"), "study").get("kind")
    except ConfigError as exc:
        raise fail(str(exc)) from None
    if kind == "claims":
        _claims(study, out_dir, quiet)
        return
    try:
        load_study(study)
        prepare_output(out_dir, resume, overwrite)
    except (ConfigError, OutputError) as exc:
        raise fail(str(exc)) from None

    def on_case(case: CaseRun, folder: Path, reused: bool) -> None:
        out.print(f"{case.label}: {'finished earlier, kept' if reused else 'done'} ({folder}/)")

    try:
        written = run_study(study, out_dir, not quiet, resume, overwrite, on_case)
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {len(written)} entries under {out_dir}/ (study.csv, study.png)")


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
    from agents.config import load_train_config, train_config_source
    from agents.training import plan_training, run_training

    sets = list(set_ or []) + ([f"seed={seed}"] if seed is not None else [])
    try:
        cfg = load_train_config(config, sets)
        plan = plan_training(
            cfg,
            out_dir,
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
        raise fail(f"{model}: no such model file")
    if trials < 1:
        raise fail("--trials must be at least 1")
    try:
        policy = Policy(model)
        cfg = load_config(scenario or policy.cfg.scenario, list(set_ or []))
    except ConfigError as exc:
        raise fail(str(exc)) from None
    res = run_benchmark(cfg, [f"policy:{model}"], trials=trials, seed=seed, progress=not quiet)
    write_bench(res, out_dir)
    out.print((out_dir / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)


def _claims(study: str, out_dir: Path, quiet: bool) -> None:
    from qkf.core.io import OutputError, check_output_dir
    from qkf.transfer_alignment.claims import load_claims, run_claims
    from qkf.transfer_alignment.methods import MethodOutputError

    try:
        load_claims(study)
        check_output_dir(out_dir)
        run_claims(study, out_dir, progress=not quiet)
    except (ConfigError, MethodOutputError, OutputError) as exc:
        raise fail(str(exc)) from None
    text = (out_dir / "claims.md").read_text()
    out.print(text, soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {out_dir}/ (claims.csv, claims.md, one benchmark folder per config)")


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
    Path | None,
    typer.Option(
        "--work", help="Work folder (checkpoints, logs, bench outputs): results/zoo/NAME."
    ),
]


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
    try:
        chosen_seeds = [int(s) for s in seeds.split(",")] if seeds else None
    except ValueError:
        raise fail(f"--seeds: {seeds!r} is not a comma-separated list of integers") from None
    if chosen_seeds is not None and any(s < 0 for s in chosen_seeds):
        raise fail("--seeds: seeds must be non-negative")
    folder = work or Path("results/zoo") / entry.name
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
) -> None:
    """Judge every trained seed against the baselines and the oracle on held-out benchmark
    seeds; writes evaluation/ and card.md of the entry."""
    from agents.zoo.commands import evaluate_entry

    entry = _entry(name)
    if trials is not None and not 2 <= trials <= MAX_TRIALS:
        raise fail(f"--trials must be between 2 and {MAX_TRIALS:,}")
    folder = work or Path("results/zoo") / entry.name
    try:
        path = evaluate_entry(entry, folder, trials, not quiet, lambda m: out.print(m))
    except (ConfigError, FileNotFoundError) as exc:
        raise fail(str(exc)) from None
    text = (entry.folder / "card.md").read_text()
    out.print(text, soft_wrap=True, markup=False, highlight=False)
    out.print(f"wrote {path}")


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
