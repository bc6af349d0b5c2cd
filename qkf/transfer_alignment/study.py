"""Studies: one command that runs a set of cases (benchmarks or CRLBs) and plots them together.

A study file (``configs/studies/*.yaml``)::

    name: matching
    kind: bench                 # bench: Monte Carlo of ``methods``; crlb: the bound only
    base: ../paper.yaml         # config every case starts from (relative to the study file)
    methods: [kf]
    trials: 50
    seed: 0
    metric: att_arcsec_avg      # summary column plotted against the cases
    cases:
      - {label: attitude, set: [filter.matching=attitude]}
      - {label: attitude + rate, set: [filter.matching=attitude_rate]}

A case may name its own ``base``. Output: one folder per case (the files of ``qkf bench`` or
``crlb.csv``), ``study.csv`` (one row per case and method) and ``study.png``.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from qkf.core import presets
from qkf.core.config import ConfigError, StrictModel, read_yaml_mapping, validate
from qkf.core.io import (
    OutputError,
    atomic_write_bytes,
    atomic_write_csv,
    check_output_dir,
    slug,
    staged_directory,
)
from qkf.core.manifest import manifest, read_manifest, write_manifest
from qkf.core.plotting import figure_png, plt
from qkf.transfer_alignment.benchmark import (
    NEES_COLUMNS,
    BenchResult,
    parse_methods,
    run_benchmark,
)
from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.crlb import CrlbResult, crlb
from qkf.transfer_alignment.methods import NamedMethod
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, group_rms, summarize
from qkf.transfer_alignment.report import (
    INTERVAL_COLUMNS,
    SUMMARY_COLUMNS,
    UNITS,
    load_bench,
    method_style,
    summary_rows,
    write_bench,
    write_crlb_csv,
)
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES


class Case(StrictModel):
    label: str
    base: str | None = None
    set: list[str] = Field(default_factory=list)


class Study(StrictModel):
    name: str
    description: str = ""
    kind: Literal["bench", "crlb"] = "bench"
    base: str
    methods: list[str] = Field(default_factory=lambda: ["kf"])
    trials: Annotated[int, Field(ge=1)] = 20
    seed: Annotated[int, Field(ge=0)] = 0
    metric: str = "ma_urad_settled"
    cases: list[Case] = Field(min_length=1)


@dataclass(frozen=True)
class CaseRun:
    """One case of a study or a sweep: its label, output folder name and config."""

    label: str
    folder: str
    cfg: Config


@dataclass
class CaseResult:
    case: CaseRun
    bound: CrlbResult
    bench: BenchResult | None  # None for a CRLB-only study


def run_case(
    case: CaseRun,
    methods: list[Any] | None,
    trials: int | None = None,
    seed: int | None = None,
    progress: bool = True,
    backend: str = "local",
    workers: int | None = None,
) -> CaseResult:
    """The CRLB of a case and, unless ``methods`` is None, its Monte Carlo benchmark."""
    bound = crlb(case.cfg)
    if methods is None:
        return CaseResult(case, bound, None)
    res = run_benchmark(case.cfg, methods, trials, seed, progress, backend, workers)
    return CaseResult(case, bound, res)


def case_rows(result: CaseResult) -> list[list[object]]:
    """Summary rows of a case, the case label first (``study.csv``, ``sweep_summary.csv``)."""
    if result.bench is None:
        cfg = result.case.cfg
        summary = summarize(result.bound.bound / DISPLAY_UNIT, result.bound.t, cfg.run.settled_s)
        cells = [summary[c[: -len(s)] if (s := _suffix(c)) else c] for c in INTERVAL_COLUMNS]
        return [[result.case.label, "crlb", 0, 0, *cells, *[""] * len(NEES_COLUMNS), 0.0]]
    return [[result.case.label, *row] for row in summary_rows(result.bench)]


def _suffix(column: str) -> str:
    return next((s for s in ("_lo", "_hi") if column.endswith(s)), "")


def write_case(result: CaseResult, folder: Path) -> list[Path]:
    """The files of one case, written as one: those of ``qkf bench``, or ``crlb.csv`` and
    ``run.json``."""
    if result.bench is not None:
        return write_bench(result.bench, folder)
    with staged_directory(folder) as stage:
        write_crlb_csv(stage / "crlb.csv", result.bound)
        write_manifest(stage, manifest("crlb", result.case.cfg.model_dump(mode="json")))
    return [folder / "crlb.csv", folder / "run.json"]


def _finished(case: CaseRun, folder: Path, methods: list[Any], trials: int, seed: int) -> bool:
    """A case folder that holds a complete benchmark of exactly this case."""
    try:
        info = read_manifest(folder, "bench")
    except ConfigError:
        return False
    specs = [m.get("spec") for m in info.get("methods", [])]
    wanted = [m.spec if isinstance(m, NamedMethod) else m for m in methods]
    return (
        info["config"] == case.cfg.model_dump(mode="json")
        and specs == wanted
        and info.get("trials") == trials
        and info.get("seed") == seed
    )


def prepare_output(out: Path, resume: bool, overwrite: bool) -> None:
    """Refuse an output folder that holds something else, unless told to resume or replace.

    A study or sweep writes each case folder whole as soon as it is done, so an interrupted run
    can be finished with ``resume`` (finished cases are read back, not recomputed).
    """
    check_output_dir(out)
    if resume and overwrite:
        raise OutputError("--resume and --overwrite exclude each other")
    if out.is_dir() and any(out.iterdir()) and not (resume or overwrite):
        raise OutputError(
            f"{out}: holds an earlier run; --resume finishes it, --overwrite replaces it"
        )


def run_cases(
    cases: list[CaseRun],
    methods: list[Any] | None,
    out: Path,
    trials: int,
    seed: int,
    resume: bool = False,
    on_case: Callable[[CaseRun, Path, bool], None] | None = None,
    **bench: Any,
) -> list[CaseResult]:
    """Run the cases into ``out/<case folder>/``, each written whole as soon as it is done;
    with ``resume``, a case whose folder already holds its complete run is read back instead.
    ``on_case(case, folder, reused)`` is called after each. ``bench``: ``run_benchmark``
    options (progress, backend, workers)."""
    results = []
    for case in cases:
        folder = out / case.folder
        reused = resume and methods is not None and _finished(case, folder, methods, trials, seed)
        if reused:
            result = CaseResult(case, crlb(case.cfg), load_bench(folder))
        else:
            result = run_case(case, methods, trials, seed, **bench)
            write_case(result, folder)
        results.append(result)
        if on_case is not None:
            on_case(case, folder, reused)
    return results


def _remove_stale(out: Path, keep: set[str]) -> None:
    """Remove what an earlier run left in ``out`` that this run did not write: case folders
    (recognised by their ``run.json``) and the summary files of studies and sweeps."""
    ours = {"study.csv", "study.png", "sweep_summary.csv", "run.json"}
    for entry in out.iterdir():
        if entry.name in keep:
            continue
        if entry.is_dir() and (entry / "run.json").is_file():
            shutil.rmtree(entry)
        elif entry.is_file() and entry.name in ours:
            entry.unlink()


@contextmanager
def _output(out: Path, resume: bool, overwrite: bool) -> Iterator[Path]:
    """Where a study or sweep writes: ``out`` itself (fresh or resumed), or, with
    ``overwrite``, a staging folder swapped in whole at the end."""
    prepare_output(out, resume, overwrite)
    if overwrite:
        with staged_directory(out) as stage:
            yield stage
    else:
        out.mkdir(parents=True, exist_ok=True)
        yield out


# ---- sweeps: one config value over a list (``sweep:`` in a scenario config) -------------------


def sweep_cases(config: str | Path, sets: list[str], cfg: Config) -> list[CaseRun]:
    """The cases of ``cfg.sweep``: the config reloaded with ``--set key=value`` per value (each
    case's own config has no sweep: its manifest reruns that case alone)."""
    assert cfg.sweep is not None
    key = cfg.sweep.key
    leaf = key.split(".")[-1]
    cases = []
    for v in cfg.sweep.values:
        case_cfg = load_config(config, [*sets, f"{key}={v}"]).model_copy(update={"sweep": None})
        cases.append(CaseRun(str(v), f"{leaf}={slug(v)}", case_cfg))
    return cases


def run_sweep(
    cases: list[CaseRun],
    key: str,
    methods: list[Any],
    out_dir: str | Path,
    trials: int | None = None,
    seed: int | None = None,
    resume: bool = False,
    overwrite: bool = False,
    on_case: Callable[[CaseRun, Path, bool], None] | None = None,
    **bench: Any,
) -> Path:
    """Run each case into ``OUT/<leaf>=<value>/`` (written as soon as it is done), then
    ``OUT/sweep_summary.csv``; returns the latter. ``bench``: options of ``run_benchmark``."""
    out = Path(out_dir)
    run = cases[0].cfg.run
    n, s = trials or run.trials, run.seed if seed is None else seed
    with _output(out, resume, overwrite) as where:
        results = run_cases(cases, methods, where, n, s, resume, on_case, **bench)
        rows = [row for r in results for row in case_rows(r)]
        atomic_write_csv(where / "sweep_summary.csv", (key, *SUMMARY_COLUMNS), rows)
        _remove_stale(where, {c.folder for c in cases} | {"sweep_summary.csv"})
    return out / "sweep_summary.csv"


# ---- studies: named cases from a study file, plotted together --------------------------------


def load_study(path: str | Path) -> tuple[Study, list[Config]]:
    """Read a study (a path or a preset name) and the config of each case.

    ``ConfigError`` names the study file and, for a case, its index and label.
    """
    path = presets.resolve(path, "studies")
    study = validate(Study, read_yaml_mapping(path, "study"), str(path), "study")
    if study.kind == "bench" and study.metric not in METRIC_COLUMNS:
        raise ConfigError(f"{path}: metric: must be one of {', '.join(METRIC_COLUMNS)}")
    if study.kind == "bench":
        try:
            parse_methods(study.methods)
        except ValueError as exc:
            raise ConfigError(f"{path}: methods: {exc}") from None
    configs = []
    for i, case in enumerate(study.cases):
        try:
            configs.append(
                load_config((path.parent / (case.base or study.base)).resolve(), case.set)
            )
        except ConfigError as exc:
            raise ConfigError(f"{path}: cases.{i} ({case.label}): {exc}") from None
    return study, configs


def run_study(
    path: str | Path,
    out_dir: str | Path,
    progress: bool = True,
    resume: bool = False,
    overwrite: bool = False,
    on_case: Callable[[CaseRun, Path, bool], None] | None = None,
) -> list[Path]:
    """Run every case (each case folder written as soon as it is done), then ``study.csv`` and
    ``study.png``."""
    study, configs = load_study(path)
    out = Path(out_dir)
    methods = study.methods if study.kind == "bench" else None
    cases = [
        CaseRun(case.label, slug(case.label).strip("_") or "case", cfg)
        for case, cfg in zip(study.cases, configs, strict=True)
    ]
    with _output(out, resume, overwrite) as where:
        results = run_cases(
            cases, methods, where, study.trials, study.seed, resume, on_case, progress=progress
        )
        rows = [row for r in results for row in case_rows(r)]
        atomic_write_csv(where / "study.csv", ("case", *SUMMARY_COLUMNS), rows)
        level = configs[0].run.bootstrap.level
        png = _study_png(study, _curves(results), rows, level)
        atomic_write_bytes(where / "study.png", png)
        _remove_stale(where, {c.folder for c in cases} | {"study.csv", "study.png"})
    return [*(out / c.folder for c in cases), out / "study.csv", out / "study.png"]


Curve = tuple[str, str, np.ndarray, dict[str, np.ndarray]]  # case, method, t, group RMS


def _curves(results: list[CaseResult]) -> list[Curve]:
    curves: list[Curve] = []
    for r in results:
        t = r.bound.t
        curves.append((r.case.label, "CRLB", t, group_rms((r.bound.bound / DISPLAY_UNIT) ** 2)))
        for m in r.bench.methods if r.bench is not None else []:
            curves.append((r.case.label, m.name, t, group_rms((m.rms / DISPLAY_UNIT) ** 2)))
    return curves


CASE_STYLES: tuple[Any, ...] = ("-", "--", "-.", ":", (0, (5, 1)), (0, (3, 1, 1, 1)))


def _study_png(study: Study, curves: list[Curve], rows: list[list[object]], level: float) -> bytes:
    """RMS vs time per group (colour: method, the same in every panel; dash: case) and the
    study's metric per case and method with its bootstrap interval as error bars."""
    fig = plt.figure(figsize=(13, 10))
    grid = fig.add_gridspec(3, 2, height_ratios=[1, 1, 1.0])
    axes = [fig.add_subplot(grid[i // 2, i % 2]) for i in range(4)]
    methods = list(dict.fromkeys(str(r[1]) for r in rows))
    cases = [c.label for c in study.cases]
    color = {m: method_style(i, 2)["color"] for i, m in enumerate(methods)}
    color["CRLB"] = "k"
    for ax, (g, title) in zip(axes, GROUP_TITLES.items(), strict=True):
        for case, what, t, groups in curves:
            ls = CASE_STYLES[cases.index(case) % len(CASE_STYLES)]
            lw = 0.9 if what == "CRLB" else 1.3
            ax.semilogy(t, groups[g], ls=ls, lw=lw, color=color.get(what, "k"),
                        label=f"{case}: {what}")  # fmt: skip
        ax.set_title(title)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"RMS [{UNITS[g]}]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(grid[2, :])
    metric = study.metric if study.kind == "bench" else "ma_urad_settled"
    col = SUMMARY_COLUMNS.index(metric) + 1  # rows carry the case label first
    width = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        cells = [next((r for r in rows if r[0] == lab and r[1] == m), None) for lab in cases]
        vals = np.array([float(str(r[col])) if r else np.nan for r in cells])
        err = None
        if m != "crlb":
            lo = np.array([float(str(r[col + 1])) if r else np.nan for r in cells])
            hi = np.array([float(str(r[col + 2])) if r else np.nan for r in cells])
            err = np.vstack([vals - lo, hi - vals])
        ax.bar(np.arange(len(cases)) + j * width, vals, width, yerr=err, capsize=3,
               color=color.get(m, "0.5"), label=m)  # fmt: skip
    ax.set_xticks(np.arange(len(cases)) + 0.4 - width / 2, cases, rotation=15, ha="right")
    ax.set_yscale("log")
    group = next(g for g in UNITS if metric.startswith(g))
    window = metric[len(group) + 1 :]
    ax.set_ylabel(f"{metric} [{UNITS[group]}]")
    ax.set_title(f"{metric}: RMS over the {window} window, per case "
                 f"(error bars: {100 * level:g} % bootstrap over trials)")  # fmt: skip
    ax.legend(fontsize=8, ncol=min(5, len(methods)))
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.suptitle(f"study {study.name}" + (f": {study.description}" if study.description else ""))
    fig.tight_layout()
    return figure_png(fig)


__all__ = ["CaseRun", "Study", "load_study", "run_study", "run_sweep", "sweep_cases"]
