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

from pathlib import Path
from typing import Annotated, Literal

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from qkf.transfer_alignment.benchmark import BenchResult, run_benchmark
from qkf.transfer_alignment.config import Config, ConfigError, load_config
from qkf.transfer_alignment.crlb import CrlbResult, crlb
from qkf.core.io import atomic_write_bytes, atomic_write_csv, slug
from qkf.transfer_alignment.metrics import group_rms, summarize
from qkf.transfer_alignment.report import SUMMARY_COLUMNS, figure_png, summary_rows, write_bench, write_crlb_csv
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES


class Case(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    label: str
    base: str | None = None
    set: list[str] = Field(default_factory=list)


class Study(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    description: str = ""
    kind: Literal["bench", "crlb"] = "bench"
    base: str
    methods: list[str] = Field(default_factory=lambda: ["kf"])
    trials: Annotated[int, Field(ge=1)] = 20
    seed: Annotated[int, Field(ge=0)] = 0
    metric: str = "ma_urad_avg"
    cases: list[Case] = Field(min_length=1)


def load_study(path: str | Path) -> tuple[Study, list[Config]]:
    """Read a study and the config of each case; ``ConfigError`` names the file and field."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such study file")
    try:
        study = Study.model_validate(yaml.safe_load(path.read_text()) or {})
    except (ValidationError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: invalid study: {exc}") from None
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
    rows: list[list[object]] = []
    curves: list[
        tuple[str, np.ndarray, dict[str, np.ndarray], bool]
    ] = []  # label, t, groups, bound?
    pending: list[tuple[Case, CrlbResult, BenchResult | None]] = []
    for case, cfg in zip(study.cases, configs, strict=True):
        bound = crlb(cfg)
        t = bound.t
        curves.append(
            (f"{case.label}: CRLB", t, group_rms((bound.bound / DISPLAY_UNIT) ** 2), True)
        )
        if study.kind == "crlb":
            rows.append(
                [case.label, "crlb", 0, *summarize(bound.bound / DISPLAY_UNIT).values(), 0.0]
            )
            pending.append((case, bound, None))
            continue
        res = run_benchmark(cfg, study.methods, study.trials, study.seed, progress=progress)
        for m in res.methods:
            curves.append(
                (f"{case.label}: {m.name}", t, group_rms((m.rms / DISPLAY_UNIT) ** 2), False)
            )
        rows += [[case.label, *row] for row in summary_rows(res)]
        pending.append((case, bound, res))
    # everything computed: now write
    written = []
    for case, bound, result in pending:
        sub = out / (slug(case.label).strip("_") or "case")
        if result is None:
            write_crlb_csv(sub / "crlb.csv", bound)
            written.append(sub / "crlb.csv")
        else:
            written += write_bench(result, sub)
    atomic_write_csv(out / "study.csv", ("case", *SUMMARY_COLUMNS), rows)
    atomic_write_bytes(out / "study.png", _study_png(study, curves, rows))
    return [*written, out / "study.csv", out / "study.png"]


def _study_png(
    study: Study,
    curves: list[tuple[str, np.ndarray, dict[str, np.ndarray], bool]],
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


__all__ = ["Study", "load_study", "run_study"]
