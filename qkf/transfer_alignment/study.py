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

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from qkf.core import presets
from qkf.core.config import ConfigError, StrictModel, read_yaml_mapping, validate
from qkf.core.io import atomic_write_bytes, atomic_write_csv, slug
from qkf.core.plotting import figure_png, plt
from qkf.transfer_alignment.benchmark import BenchResult, run_benchmark
from qkf.transfer_alignment.config import Config, load_config
from qkf.transfer_alignment.crlb import CrlbResult, crlb
from qkf.transfer_alignment.metrics import group_rms, summarize
from qkf.transfer_alignment.report import (
    SUMMARY_COLUMNS,
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
    metric: str = "ma_urad_avg"
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
    methods: list[str] | None,
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
        summary = summarize(result.bound.bound / DISPLAY_UNIT)
        return [[result.case.label, "crlb", 0, *summary.values(), 0.0]]
    return [[result.case.label, *row] for row in summary_rows(result.bench)]


def write_case(result: CaseResult, folder: Path) -> list[Path]:
    """The files of one case: those of ``qkf bench``, or ``crlb.csv`` alone."""
    if result.bench is None:
        write_crlb_csv(folder / "crlb.csv", result.bound)
        return [folder / "crlb.csv"]
    return write_bench(result.bench, folder)


# ---- sweeps: one config value over a list (``sweep:`` in a scenario config) -------------------


def sweep_cases(config: str | Path, sets: list[str], cfg: Config) -> list[CaseRun]:
    """The cases of ``cfg.sweep``: the config reloaded with ``--set key=value`` per value."""
    assert cfg.sweep is not None
    key = cfg.sweep.key
    leaf = key.split(".")[-1]
    return [
        CaseRun(str(v), f"{leaf}={slug(v)}", load_config(config, [*sets, f"{key}={v}"]))
        for v in cfg.sweep.values
    ]


def run_sweep(
    cases: list[CaseRun],
    key: str,
    methods: list[str],
    out_dir: str | Path,
    on_case: Callable[[CaseRun, Path], None] | None = None,
    **bench: Any,
) -> Path:
    """Run each case into ``OUT/<leaf>=<value>/`` (written as soon as it is done), then
    ``OUT/sweep_summary.csv``; returns the latter. ``bench``: options of ``run_benchmark``."""
    out = Path(out_dir)
    rows: list[list[object]] = []
    for case in cases:
        result = run_case(case, methods, **bench)
        write_case(result, out / case.folder)
        rows += case_rows(result)
        if on_case is not None:
            on_case(case, out / case.folder)
    atomic_write_csv(out / "sweep_summary.csv", (key, *SUMMARY_COLUMNS), rows)
    return out / "sweep_summary.csv"


# ---- studies: named cases from a study file, plotted together --------------------------------


def load_study(path: str | Path) -> tuple[Study, list[Config]]:
    """Read a study (a path or a preset name) and the config of each case.

    ``ConfigError`` names the file and the field.
    """
    path = presets.resolve(path, "studies")
    study = validate(Study, read_yaml_mapping(path, "study"), str(path), "study")
    if study.kind == "bench" and study.metric not in SUMMARY_COLUMNS[2:-1]:
        raise ConfigError(f"{path}: metric: must be one of {', '.join(SUMMARY_COLUMNS[2:-1])}")
    configs = [
        load_config((path.parent / (case.base or study.base)).resolve(), case.set)
        for case in study.cases
    ]
    return study, configs


def run_study(path: str | Path, out_dir: str | Path, progress: bool = True) -> list[Path]:
    """Run every case, then write the case folders, ``study.csv`` and ``study.png``."""
    study, configs = load_study(path)
    out = Path(out_dir)
    methods = study.methods if study.kind == "bench" else None
    results = [
        run_case(
            CaseRun(case.label, slug(case.label).strip("_") or "case", cfg),
            methods,
            study.trials,
            study.seed,
            progress,
        )
        for case, cfg in zip(study.cases, configs, strict=True)
    ]
    # everything computed: now write
    written: list[Path] = []
    rows: list[list[object]] = []
    for result in results:
        written += write_case(result, out / result.case.folder)
        rows += case_rows(result)
    atomic_write_csv(out / "study.csv", ("case", *SUMMARY_COLUMNS), rows)
    atomic_write_bytes(out / "study.png", _study_png(study, _curves(results), rows))
    return [*written, out / "study.csv", out / "study.png"]


Curve = tuple[str, np.ndarray, dict[str, np.ndarray], bool]  # label, t, group RMS, is bound


def _curves(results: list[CaseResult]) -> list[Curve]:
    curves: list[Curve] = []
    for r in results:
        t = r.bound.t
        label = r.case.label
        curves.append((f"{label}: CRLB", t, group_rms((r.bound.bound / DISPLAY_UNIT) ** 2), True))
        for m in r.bench.methods if r.bench is not None else []:
            curves.append((f"{label}: {m.name}", t, group_rms((m.rms / DISPLAY_UNIT) ** 2), False))
    return curves


def _study_png(
    study: Study,
    curves: list[Curve],
    rows: list[list[object]],
) -> bytes:
    fig = plt.figure(figsize=(13, 9))
    grid = fig.add_gridspec(3, 2, height_ratios=[1, 1, 0.9])
    axes = [fig.add_subplot(grid[i // 2, i % 2]) for i in range(4)]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    case_color = {case.label: colors[i % len(colors)] for i, case in enumerate(study.cases)}
    styles = ["-", "-.", ":", (0, (5, 1)), (0, (3, 1, 1, 1))]
    for ax, (g, title) in zip(axes, GROUP_TITLES.items(), strict=True):
        for label, t, groups, is_bound in curves:
            case_label, what = label.split(": ", 1)
            ls = "--" if is_bound else styles[study.methods.index(what) % len(styles)]
            lw = 0.9 if is_bound else 1.3
            ax.semilogy(t, groups[g], ls=ls, lw=lw, color=case_color[case_label], label=label)
        ax.set_title(title)
        ax.set_xlabel("time [s]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(grid[2, :])
    metric = study.metric if study.kind == "bench" else "ma_urad_final"
    col = SUMMARY_COLUMNS.index(metric) + 1  # rows carry the case label first
    labels = [c.label for c in study.cases]
    methods = sorted({str(r[1]) for r in rows}, key=lambda m: [str(r[1]) for r in rows].index(m))
    width = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        vals = [
            next(float(str(r[col])) for r in rows if r[0] == lab and r[1] == m) for lab in labels
        ]
        ax.bar(np.arange(len(labels)) + j * width, vals, width, label=m)
    ax.set_xticks(np.arange(len(labels)) + 0.4 - width / 2, labels)
    ax.set_yscale("log")
    ax.set_ylabel(metric)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.suptitle(f"study {study.name}" + (f": {study.description}" if study.description else ""))
    fig.tight_layout()
    return figure_png(fig)


__all__ = ["CaseRun", "Study", "load_study", "run_study", "run_sweep", "sweep_cases"]
