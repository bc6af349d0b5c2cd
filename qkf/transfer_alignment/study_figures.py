"""The figure of a study (``study.png``): the summary metric per case and method with its
interval, beside the cases' RMS curves and CRLBs (the study file: :mod:`.study`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from qkf.core.plotting import Figure, plt
from qkf.transfer_alignment.bench_figures import method_style
from qkf.transfer_alignment.cases import CaseResult
from qkf.transfer_alignment.metrics import group_rms
from qkf.transfer_alignment.report import SUMMARY_COLUMNS, UNITS
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES
from qkf.transfer_alignment.study import Study, study_cases

Curve = tuple[str, str, np.ndarray, dict[str, np.ndarray]]  # case, method, t, group RMS


def study_curves(results: list[CaseResult]) -> list[Curve]:
    curves: list[Curve] = []
    for r in results:
        t = r.bound.t
        curves.append((r.case.label, "CRLB", t, group_rms((r.bound.bound / DISPLAY_UNIT) ** 2)))
        for m in r.bench.methods if r.bench is not None else []:
            curves.append((r.case.label, m.name, t, group_rms((m.rms / DISPLAY_UNIT) ** 2)))
    return curves


def study_figure(
    study: Study, curves: list[Curve], rows: list[list[object]], level: float
) -> Figure:
    """The study's figure: RMS (and CRLB) vs time per state group, then the study's metric per
    case and method. A bench study gets small multiples, one row per group and one column per
    case (colour: method, the same everywhere; dashed black: the CRLB; y shared along a row);
    a CRLB study one panel per group with one colour per case. One legend, outside the data."""
    cases = [c.label for c in study_cases(study)]
    methods = list(dict.fromkeys(str(r[1]) for r in rows))
    color = {m: method_style(i, 2)["color"] for i, m in enumerate(methods)}
    bench = study.kind == "bench"
    ncols = len(cases) if bench else 2
    nrows = len(GROUP_TITLES) if bench else 2
    fig = plt.figure(figsize=(max(10.0, 3.3 * ncols + 1.5), 2.5 * nrows + 4.5),
                     layout="constrained")  # fmt: skip
    grid = fig.add_gridspec(nrows + 1, ncols, height_ratios=[1.0] * nrows + [1.5])
    axes = []
    for gi, (g, title) in enumerate(GROUP_TITLES.items()):
        name = title.split(" [")[0]
        if bench:
            first = None
            for ci, case in enumerate(cases):
                ax = fig.add_subplot(grid[gi, ci], sharey=first)
                first = first or ax
                for c, what, t, groups in curves:
                    if c != case:
                        continue
                    if what == "CRLB":
                        ax.semilogy(t, groups[g], "k--", lw=0.9, label="CRLB (1σ)")
                    else:
                        ax.semilogy(t, groups[g], color=color.get(what, "0.5"), lw=1.3,
                                    label=what)  # fmt: skip
                if gi == 0:
                    ax.set_title(case, fontsize=10)
                if ci == 0:
                    ax.set_ylabel(f"{name}\nRMS [{UNITS[g]}]")
                if gi == nrows - 1:
                    ax.set_xlabel("time [s]")
                ax.grid(True, which="both", alpha=0.3)
                axes.append(ax)
        else:
            ax = fig.add_subplot(grid[gi // 2, gi % 2])
            for c, _, t, groups in curves:
                ax.semilogy(t, groups[g], lw=1.3, label=c,
                            color=method_style(cases.index(c), 2)["color"])  # fmt: skip
            ax.set_title(f"{name}: CRLB (1σ)", fontsize=10)
            ax.set_ylabel(f"CRLB [{UNITS[g]}]")
            ax.set_xlabel("time [s]")
            ax.grid(True, which="both", alpha=0.3)
            axes.append(ax)
    ax = fig.add_subplot(grid[nrows, :])
    col = SUMMARY_COLUMNS.index(study.metric) + 1  # rows carry the case label first
    width = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        cells = [next((r for r in rows if r[0] == lab and r[1] == m), None) for lab in cases]
        vals = np.array([_cell(r[col]) if r else np.nan for r in cells])
        err = None
        if bench:
            lo = np.array([_cell(r[col + 1]) if r else np.nan for r in cells])
            hi = np.array([_cell(r[col + 2]) if r else np.nan for r in cells])
            err = np.vstack([vals - lo, hi - vals])
        # a CRLB study: each case's bar in the colour of its curves above
        shade = (
            color.get(m, "0.5")
            if bench
            else [method_style(i, 2)["color"] for i in range(len(cases))]
        )
        ax.bar(np.arange(len(cases)) + j * width, vals, width, yerr=err, capsize=3,
               color=shade, label=m if bench else None)  # fmt: skip
    ax.set_xticks(np.arange(len(cases)) + 0.4 - width / 2, cases, rotation=15, ha="right")
    # log only where the values span a decade or more: a log bar starts nowhere in particular,
    # so over a narrow range its length would exaggerate the differences
    shown = [_cell(r[col]) for r in rows]
    positive = [v for v in shown if np.isfinite(v) and v > 0]
    if positive and max(positive) >= 10 * min(positive):
        ax.set_yscale("log")
    group = next((g for g in UNITS if study.metric.startswith(g)), None)
    window = "settled" if group is None else study.metric[len(group) + 1 :]
    unit = "× final CRLB, all states" if group is None else UNITS[group]
    ax.set_ylabel(f"{study.metric} [{unit}]")
    if bench:
        what = (f"RMS over the {window} window, per case and method (error bars: "
                f"{100 * level:g} % bootstrap over trials)")  # fmt: skip
    else:
        what = (f"the CRLB (1σ bound) over the {window} window, per case (a bound computed, "
                "not sampled: no error bars)")  # fmt: skip
    ax.set_title(f"{study.metric}: {what}", fontsize=10)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    # one legend for the figure, below everything (the bar colours are the line colours)
    entries: dict[str, Any] = {}
    for a in axes:
        for handle, label in zip(*a.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if "CRLB (1σ)" in entries:  # the methods first, in the order of study.csv
        entries["CRLB (1σ)"] = entries.pop("CRLB (1σ)")
    fig.legend(entries.values(), entries.keys(), loc="outside lower center",
               ncol=min(6, len(entries)), fontsize=9, frameon=False)  # fmt: skip
    fig.suptitle(f"study {study.name}" + (f": {study.description}" if study.description else ""))
    return fig


def _cell(value: object) -> float:
    """A number of a study row (a float, or its text from study.csv; empty: NaN)."""
    text = str(value)
    return float(text) if text else float("nan")


__all__ = [
    "study_curves",
    "study_figure",
]
