"""Result files of ``qkf bench`` and ``qkf crlb``: CSV tables, a markdown summary and PNG plots
(display units; formats in docs/architecture.md, "Output files")."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from qkf.core.io import atomic_write_bytes, atomic_write_csv
from qkf.core.plotting import figure_png, plt
from qkf.transfer_alignment.benchmark import BenchResult
from qkf.transfer_alignment.crlb import CrlbResult
from qkf.transfer_alignment.metrics import group_rms, summarize
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES, GROUPS, STATE_COLUMNS

SUMMARY_COLUMNS: tuple[str, ...] = (
    "method",
    "trials",
    *(f"{g}_{kind}" for g in GROUPS for kind in ("final", "avg")),
    "runtime_s",
)


def write_crlb_csv(path: str | Path, result: CrlbResult) -> None:
    """``t_s`` plus the 15 one-sigma bounds in display units (docs/architecture.md)."""
    disp = result.bound / DISPLAY_UNIT
    atomic_write_csv(
        path,
        ("t_s", *STATE_COLUMNS),
        ([float(t), *map(float, row)] for t, row in zip(result.t, disp, strict=True)),
    )


def rms_groups_png(res: BenchResult) -> bytes:
    """RMS over trials vs time per state group for every method, with the CRLB."""
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5), sharex=True)
    bound_ms = (res.bound.bound / DISPLAY_UNIT) ** 2
    crlb_groups = group_rms(bound_ms)
    for ax, (g, title) in zip(axes.ravel(), GROUP_TITLES.items(), strict=True):
        for m in res.methods:
            ax.semilogy(res.t, group_rms((m.rms / DISPLAY_UNIT) ** 2)[g], label=m.name, lw=1.2)
        ax.semilogy(res.t, crlb_groups[g], "k--", lw=1.0, label="CRLB")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{res.config.name}: RMS over {res.trials} trials (seed {res.seed})")
    fig.tight_layout()
    return figure_png(fig)


def rms_states_png(res: BenchResult) -> bytes:
    """RMS over trials vs time for each of the 15 states, with the CRLB."""
    fig, axes = plt.subplots(5, 3, figsize=(13, 14), sharex=True)
    bound = res.bound.bound / DISPLAY_UNIT
    for i, ax in enumerate(axes.ravel()):
        for m in res.methods:
            ax.semilogy(res.t, m.rms[:, i] / DISPLAY_UNIT[i], lw=1.0, label=m.name)
        ax.semilogy(res.t, bound[:, i], "k--", lw=0.8, label="CRLB")
        ax.set_title(STATE_COLUMNS[i], fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return figure_png(fig)


def kappa_png(res: BenchResult) -> bytes | None:
    """κ chosen over time by each adaptive method: median and 10–90 % band over trials."""
    traced = [m for m in res.methods if m.kappa is not None]
    if not traced:
        return None
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for m in traced:
        assert m.kappa is not None
        lo, med, hi = np.percentile(m.kappa, [10, 50, 90], axis=0)
        (line,) = ax.semilogy(res.kappa_t, med, lw=1.3, label=f"{m.name} (median)")
        ax.fill_between(res.kappa_t, lo, hi, color=line.get_color(), alpha=0.15, lw=0)
    acts = res.config.adaptive.actions.values()
    ax.set_ylim(min(acts) / 1.5, max(acts) * 1.5)
    for j in res.config.scenario.calibration_jumps:
        ax.axvline(j.t_s, color="k", ls=":", lw=1)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("κ  (q_p = κ · q_p0)")
    ax.set_title(f"{res.config.name}: process-noise factor in use (band: 10–90 % of trials)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return figure_png(fig)


def kappa_rows(res: BenchResult) -> list[list[object]]:
    """Long format: method, trial, t_s, kappa (the κ in use from t_s on)."""
    rows: list[list[object]] = []
    for m in res.methods:
        if m.kappa is None:
            continue
        for trial, trace in enumerate(m.kappa):
            rows += [
                [m.name, trial, float(t), float(k)] for t, k in zip(res.kappa_t, trace, strict=True)
            ]
    return rows


def summary_rows(res: BenchResult) -> list[list[object]]:
    return [
        [m.name, m.trials, *(m.summary[c] for c in SUMMARY_COLUMNS[2:-1]), round(m.runtime_s, 3)]
        for m in res.methods
    ]


def summary_markdown(res: BenchResult) -> str:
    cfg = res.config
    crlb_summary = summarize(res.bound.bound / DISPLAY_UNIT)
    head = ["method", "trials"]
    units = {"att_arcsec": "arcsec", "bias_degph": "deg/h", "sf_ppm": "ppm", "ma_urad": "µrad"}
    for g in GROUPS:
        name = g.split("_")[0]
        head += [f"{name} final [{units[g]}]", f"{name} avg [{units[g]}]"]
    head.append("runtime [s]")
    lines = [
        f"# qkf bench: {cfg.name}",
        "",
        f"{cfg.description}".strip(),
        "",
        f"Trials: {res.trials}, seed: {res.seed}, matching: {cfg.filter.matching}, "
        f"q_p0 = {cfg.filter.qp0:g} /s, duration {cfg.scenario.duration_s:g} s.",
        "RMS over trials; *final* = over the last 20 % of the run, *avg* = over the whole run; "
        "a group's RMS is the root of the mean square over its components.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for m in res.methods:
        vals = [f"{m.summary[c]:.4g}" for c in SUMMARY_COLUMNS[2:-1]]
        lines.append(f"| {m.name} | {m.trials} | " + " | ".join(vals) + f" | {m.runtime_s:.2f} |")
    vals = [f"{crlb_summary[c]:.4g}" for c in SUMMARY_COLUMNS[2:-1]]
    lines.append("| CRLB (1σ) | – | " + " | ".join(vals) + " | – |")
    notes = [f"- {m.name}: {note}" for m in res.methods for note in m.notes.values()]
    if notes:
        lines += ["", *notes]
    bad = [m for m in res.methods if m.diverged]
    if bad:
        lines += ["", "**Diverged trials:** " + ", ".join(f"{m.name}: {m.diverged}" for m in bad)]
    return "\n".join(lines) + "\n"


def write_bench(res: BenchResult, out_dir: str | Path) -> list[Path]:
    """Write rms.csv, summary.csv, summary.md, crlb.csv and the plots into ``out_dir``.

    Everything is rendered in memory first; each file is then replaced atomically.
    """
    out = Path(out_dir)
    rms_rows = [
        [m.name, float(t), *map(float, row)]
        for m in res.methods
        for t, row in zip(res.t, m.rms / DISPLAY_UNIT, strict=True)
    ]
    files: dict[str, bytes | tuple[tuple[str, ...], list[list[object]]]] = {
        "rms.csv": (("method", "t_s", *STATE_COLUMNS), rms_rows),
        "summary.csv": (SUMMARY_COLUMNS, summary_rows(res)),
        "summary.md": summary_markdown(res).encode(),
        "rms_groups.png": rms_groups_png(res),
        "rms_states.png": rms_states_png(res),
    }
    kpng = kappa_png(res)
    if kpng is not None:
        files["kappa.png"] = kpng
        files["kappa.csv"] = (("method", "trial", "t_s", "kappa"), kappa_rows(res))
    written = []
    for name, content in files.items():
        path = out / name
        if isinstance(content, bytes):
            atomic_write_bytes(path, content)
        else:
            atomic_write_csv(path, *content)
        written.append(path)
    write_crlb_csv(out / "crlb.csv", res.bound)
    written.append(out / "crlb.csv")
    return written


__all__ = [
    "SUMMARY_COLUMNS",
    "rms_groups_png",
    "summary_markdown",
    "write_bench",
    "write_crlb_csv",
]
