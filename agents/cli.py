"""``qkf train``, ``evaluate`` and ``zoo``: the agents' commands (docs/zoo.md). A Typer app mounted
by :mod:`qkf.cli`. Only typer and ``qkf.core`` are imported here; the commands import the agents
(and so torch) when they run.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from qkf.core.cli_support import (
    BackendOption,
    NoCacheOption,
    OverwriteOption,
    SetOption,
    backend_options,
    fail,
    out,
    out_dir,
    seed_option,
)
from qkf.core.config import ConfigError

if TYPE_CHECKING:  # the zoo is imported by its commands only (torch stays unloaded)
    from agents.zoo import ZooEntry

app = typer.Typer(add_completion=False, help="Train, evaluate and ship agents that choose κ.")


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
    from agents.training.records import remove_staging

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
    except KeyboardInterrupt:
        # Ctrl-C: --out keeps what was published (resumable); what a callback was still writing
        # into its staging folder (a checkpoint, half written) goes
        remove_staging(plan.out)
        raise
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
    no_cache: NoCacheOption = False,
) -> None:
    """Filter Monte Carlo trials with the policy's κ beside kf (and kf-tuned when its tuning
    is in the results cache: docs/caching.md); writes the files of ``qkf bench``. A policy of a
    problem without those files is pointed to ``qkf judge``."""
    from agents.policy import Policy
    from qkf.core.problem import problem_of_env

    if model.is_dir():
        raise fail(f"{model}: is a directory, not a model file (model.zip or model.npz)")
    if not model.is_file():
        raise fail(f"{model}: no such model file")
    seed_option(seed)
    try:
        policy = Policy(model)
        problem = problem_of_env(policy.cfg.env)
        if not 1 <= trials <= problem.max_trials:
            raise ConfigError(f"--trials must be between 1 and {problem.max_trials:,}")
        bench = problem.bench
        if bench is None:  # qkf bench's files are one problem's; every problem has qkf judge
            raise ConfigError(
                f"{model}: a policy of {policy.cfg.env} ({problem.name}), which has no bench "
                f"files. Judge it with: qkf judge {problem.name} --methods "
                f"{','.join(problem.methods.names()[:2])},policy:{model} --out DIR"
            )
        source = str(scenario or policy.cfg.scenario)
        cfg = problem.load_config(source, list(set_ or []))
        specs = [*bench.quick_baselines(cfg, cache=not no_cache), f"policy:{model}"]
        prepared = bench.prepare(cfg, specs, trials, source)
    except (ConfigError, ValueError) as exc:
        raise fail(str(exc)) from None
    folder = out_dir(out_path, "bench", overwrite)
    bench.run(prepared, seed, folder, progress=not quiet, cache=not no_cache)
    out.print((folder / "summary.md").read_text(), soft_wrap=True, markup=False, highlight=False)


@app.command("dataset")
def dataset_cmd(
    scenario: Annotated[str, typer.Argument(help="Scenario: a preset name or a config path.")],
    methods: Annotated[
        str,
        typer.Option(
            help="Comma-separated method specs (as qkf bench --methods: kf, glr, nis-rule, "
            "kf-tuned, …, LABEL=SPEC); one dataset each."
        ),
    ],
    trials: Annotated[
        int | None, typer.Option(help="Episodes: trials 0 … N−1 (config: run.trials).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of the trials (config: run.seed).")] = None,
    env: Annotated[
        str | None,
        typer.Option(
            help="Environment id whose episodes are recorded (default: the one environment "
            "with datasets)."
        ),
    ] = None,
    controls: Annotated[
        str, typer.Option(help="v4 controls of the action space, joined with + (kappa, reset, …).")
    ] = "kappa+reset",
    reward: Annotated[str, typer.Option(help="Reward of the environment.")] = "relative_state_gain",
    period_s: Annotated[float, typer.Option(help="Decision period, s (one step).")] = 10.0,
    out_path: Annotated[
        str, typer.Option("--out", help="Datasets folder (Minari's MINARI_DATASETS_PATH).")
    ] = "results/datasets",
    set_: SetOption = None,
    quiet: Annotated[bool, typer.Option(help="No progress bar.")] = False,
) -> None:
    """Minari datasets of --env's episodes (qkf/TransferAlignment-v4) driven by methods, one per
    method: --out/qkf/transfer-alignment-v4-SCENARIO-METHOD-v0 (docs/environment.md,
    "Datasets").

    The method's κ and calibration resets become the environment's moves; the actions stored
    are the nearest discrete ones. An existing dataset is never replaced (exit 2, nothing
    written); every input is checked before any work.
    """
    seed_option(seed)
    from envs import ENVIRONMENTS
    from qkf.core.montecarlo import progress_bar
    from qkf.core.registry import RegistryError, load_object

    with_datasets = [e for e in ENVIRONMENTS.names() if ENVIRONMENTS[e].datasets]
    if env is None and len(with_datasets) != 1:
        raise fail(f"--env: name one of the environments with datasets: "
                   f"{', '.join(with_datasets) or 'none'}")  # fmt: skip
    env = env if env is not None else with_datasets[0]
    try:
        spec = ENVIRONMENTS[env]
    except (KeyError, RegistryError) as exc:
        raise fail(f"--env: {exc}") from None
    if spec.datasets is None:
        raise fail(f"--env: {env} has no datasets; environments with them: "
                   f"{', '.join(with_datasets)}")  # fmt: skip
    builder = load_object(spec.datasets)
    try:
        plan = builder.plan(
            scenario, methods, trials, seed, controls, reward, period_s, out_path, set_ or []
        )
    except ConfigError as exc:
        raise fail(str(exc)) from None
    total = len(plan.methods) * (plan.chunks + 1)
    with progress_bar(total, "qkf dataset", enabled=not quiet, unit="parts") as bar:

        def on_method(label: str, parts: int) -> Callable[[], None]:
            bar.note(label)
            return lambda: bar(1)

        try:
            written = builder.make(plan, on_method)
        except (ConfigError, ValueError, FileExistsError) as exc:
            raise fail(str(exc)) from None
    for path in written:
        out.print(f"wrote {path}/", soft_wrap=True, markup=False, highlight=False)


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
    backend: BackendOption = "local",
    workers: Annotated[
        int | None,
        typer.Option(
            help="local backend: seeds trained at once, each in a process of its own (default: "
            "the cores over the config's torch_threads; 1: one after another, here)."
        ),
    ] = None,
) -> None:
    """Train every seed of the entry (a finished run is reused), side by side, and ship the
    best one. Each seed's network is the one a sequential run trains. --backend ray runs a
    Ray task per seed (RAY_ADDRESS, else a local cluster)."""
    from agents.zoo.commands import train_entry

    backend_options(backend, workers)
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
        chosen = train_entry(
            entry, folder, chosen_seeds, not quiet, lambda m: out.print(m), backend, workers
        )
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
    no_cache: NoCacheOption = False,
    baselines: Annotated[
        str | None,
        typer.Option(
            help="Judge against only these baselines of zoo.yaml (comma-separated labels, e.g. "
            "kf-tuned,glr): a quick look; the card then shows only them."
        ),
    ] = None,
) -> None:
    """Judge every trained seed against the baselines and the oracle on held-out benchmark
    seeds and, with a families: section in zoo.yaml, on the scenario families (qkf study
    families into --work/families/); writes evaluation/ and card.md into --work (and, with
    --update-entry, into the entry). Refused before any work: a seed of zoo.yaml without a
    model, or trained on another environment version than the entry's training config."""
    from agents.zoo.commands import check_entry, evaluate_entry
    from qkf.core.io import OutputError
    from qkf.core.problem import MethodOutputError

    entry = _entry(name)
    if trials is not None and not 2 <= trials <= entry.problem.max_trials:
        raise fail(f"--trials must be between 2 and {entry.problem.max_trials:,}")
    if not entry.trained_seeds():
        raise fail(f"{entry.folder}: no trained seed (run qkf zoo train {entry.name} first)")
    try:
        check_entry(entry)
    except ConfigError as exc:
        raise fail(str(exc)) from None
    folder = _work(work, entry)
    try:  # evaluate_entry checks the families study and the work folder before any work
        card = evaluate_entry(
            entry, folder, trials, not quiet, lambda m: out.print(m), update_entry,
            cache=not no_cache,
            baselines=None if baselines is None else [b.strip() for b in baselines.split(",")],
        )  # fmt: skip
    except (ConfigError, FileNotFoundError, OutputError, MethodOutputError) as exc:
        raise fail(str(exc)) from None
    out.print(card.read_text(), soft_wrap=True, markup=False, highlight=False)
    written = f"{folder / 'card.md'}" + (f" and {card}" if update_entry else "")
    out.print(f"wrote {written}")


@zoo_app.command("promote")
def zoo_promote_cmd(
    name: Annotated[str, typer.Argument(help="Zoo entry (agents/zoo/NAME).")],
) -> None:
    """Copy the entry's shipped policy and card to agents/zoo/best/ (an entry of another
    problem than transfer alignment: agents/zoo/best_<problem>/)."""
    from agents.zoo.commands import promote

    try:
        best = promote(_entry(name))
    except FileNotFoundError as exc:
        raise fail(str(exc)) from None
    out.print(f"wrote {best}/")


app.add_typer(zoo_app, name="zoo")
