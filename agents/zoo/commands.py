"""What ``qkf zoo train``, ``qkf zoo evaluate`` and ``qkf zoo promote`` do (docs/zoo.md).

* **train**: every training seed of the entry is trained into the work folder
  (``results/zoo/<name>/seed_<s>/``, checkpoints and logs included; a finished run is not
  repeated, an interrupted one goes on from its checkpoint). The model, the exact config, the
  records and the evaluations on the held-out environment seed are copied into the entry's
  ``seed_<s>/``; the seed with the best last evaluation is copied to the entry's top.
* **evaluate**: for each judging case one benchmark runs the baselines, the oracle and the
  policy of *every* training seed on the same trials (benchmark seeds, disjoint from the
  environment seeds the agents were trained on); the bench outputs, the per-trial tables, the
  summary (:mod:`agents.zoo.summary`) and the card go to the work folder. The shipped entry
  (``evaluation/``, ``card.md``, tracked in git) changes only with ``update_entry``
  (``--update-entry``), so a quick ``--trials 2`` look never rewrites the published judgement.
* **promote**: copy an entry's shipped policy and card to ``agents/zoo/best/``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from agents.config import load_train_config
from agents.training import plan_training, run_training
from agents.training.records import EVALUATIONS
from agents.zoo.card import write_card
from agents.zoo.entry import ZOO_DIR, JudgeCase, ZooEntry
from agents.zoo.summary import judge_summary, write_summary
from qkf.core.io import atomic_write_bytes

PROMOTED = ("config.yaml", "card.md", "SOURCE")
"""What ``promote`` writes into ``best/`` besides the model."""
SEED_FILES = ("config.yaml", "training.json")
"""Copied from a training run into the entry's ``seed_<s>/`` (with the model and
``eval/evaluations.npz`` as ``evaluations.npz``)."""


def _copy(src: Path, dst: Path) -> None:
    atomic_write_bytes(dst, src.read_bytes())


def train_entry(
    entry: ZooEntry,
    work: Path,
    seeds: list[int] | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
) -> int | None:
    """Train the entry's seeds (default: all of ``zoo.yaml``); returns the shipped seed."""
    for seed in seeds if seeds is not None else entry.spec.seeds:
        cfg = load_train_config(entry.train_source, [f"seed={seed}"])
        run_dir = work / f"seed_{seed}"
        plan = plan_training(cfg, run_dir, source=f"{entry.train_source} (seed {seed})")
        say(f"seed {seed}: {'already trained' if plan.complete else ', '.join(plan.notes)}")
        model = run_training(plan, progress=progress)
        dst = entry.seed_dir(seed)
        dst.mkdir(parents=True, exist_ok=True)
        _copy(model, dst / model.name)
        for name in SEED_FILES:
            _copy(run_dir / name, dst / name)
        evaluations = run_dir / EVALUATIONS
        if evaluations.is_file():
            _copy(evaluations, dst / "evaluations.npz")
    chosen = entry.selected_seed()
    if chosen is not None:
        for name in (entry.model_name(), "config.yaml"):
            _copy(entry.seed_dir(chosen) / name, entry.folder / name)
    write_card(entry)
    return chosen


def policy_methods(entry: ZooEntry) -> list[str]:
    """``LABEL=policy:PATH`` of every trained seed: ``<name>:s<seed>``."""
    return [f"{entry.name}:s{s}=policy:{entry.seed_model(s)}" for s in entry.trained_seeds()]


def evaluate_case(
    entry: ZooEntry, case: JudgeCase, work: Path, trials: int | None, progress: bool
) -> Path:
    """One judging benchmark; returns its bench folder (in the work folder)."""
    from qkf.transfer_alignment.benchmark import parse_methods, run_benchmark
    from qkf.transfer_alignment.config import load_config
    from qkf.transfer_alignment.report import write_bench

    cfg = load_config(case.scenario, list(case.overrides))
    specs = [*case.baselines, *(["oracle"] if case.oracle else []), *policy_methods(entry)]
    res = run_benchmark(
        cfg, parse_methods(",".join(specs)), trials or case.trials, case.seed, progress=progress
    )
    folder = work / f"judge_{Path(case.scenario).stem}_seed{case.seed}"
    write_bench(res, folder)
    return folder


def evaluate_entry(
    entry: ZooEntry,
    work: Path,
    trials: int | None = None,
    progress: bool = True,
    say: Callable[[str], None] = print,
    update_entry: bool = False,
) -> Path:
    """Judge every trained seed on every case; writes ``evaluation/`` and ``card.md`` into the
    work folder, and with ``update_entry`` into the entry as well. Returns the card's path."""
    if not entry.trained_seeds():
        raise FileNotFoundError(f"{entry.folder}: no trained seed (run qkf zoo train first)")
    rows = []
    dst = work / "evaluation"
    dst.mkdir(parents=True, exist_ok=True)
    for case in entry.spec.cases():
        say(f"judging on {case.scenario}, benchmark seed {case.seed}")
        folder = evaluate_case(entry, case, work, trials, progress)
        stem = f"{Path(case.scenario).stem}_seed{case.seed}"
        _copy(folder / "trials.csv", dst / f"{stem}_trials.csv")
        _copy(folder / "summary.md", dst / f"{stem}_summary.md")
        rows += judge_summary(entry, case, folder / "trials.csv")
    write_summary(rows, dst / "zoo_summary.csv")
    card = write_card(entry, work)
    if update_entry:
        shipped = entry.folder / "evaluation"
        shipped.mkdir(exist_ok=True)
        for src in sorted(dst.iterdir()):
            _copy(src, shipped / src.name)
        card = write_card(entry)
    return card


def promote(entry: ZooEntry, zoo: Path = ZOO_DIR) -> Path:
    """Copy the entry's shipped policy, config and card to ``zoo/best/``."""
    best = zoo / "best"
    model = entry.folder / entry.model_name()
    if not model.is_file():
        raise FileNotFoundError(f"{model}: the entry has no shipped model (qkf zoo train)")
    best.mkdir(exist_ok=True)
    # only what an earlier promote wrote goes: best/ holds nothing else of anyone's
    for name in (*PROMOTED, "model.zip", "model.npz"):
        (best / name).unlink(missing_ok=True)
    for name in (entry.model_name(), *PROMOTED):
        if (entry.folder / name).is_file():
            _copy(entry.folder / name, best / name)
    atomic_write_bytes(best / "SOURCE", f"{entry.name}\n".encode())
    return best


__all__ = ["evaluate_case", "evaluate_entry", "policy_methods", "promote", "train_entry"]
