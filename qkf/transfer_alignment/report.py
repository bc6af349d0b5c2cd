"""Result files of ``qkf bench`` and ``qkf crlb``: CSV tables, a markdown summary and PNG plots
(display units; formats in docs/architecture.md, "Output files")."""

from __future__ import annotations

import csv
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.config import ConfigError, validate
from qkf.core.io import atomic_write_bytes, csv_text, staged_directory
from qkf.core.manifest import manifest, read_manifest, write_manifest
from qkf.core.plotting import Figure, figure_png, plt
from qkf.core.stats import average_nees_band, min_verdict_trials
from qkf.transfer_alignment.benchmark import NEES_COLUMNS, BenchResult, MethodResult
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import CrlbResult
from qkf.transfer_alignment.divergence import divergence_lines
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.metrics import (
    METRIC_COLUMNS,
    WINDOWS,
    group_rms,
    recovery_times,
    summarize,
)
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES, STATE_COLUMNS

INTERVAL_COLUMNS: tuple[str, ...] = tuple(
    f"{c}{suffix}" for c in METRIC_COLUMNS for suffix in ("", "_lo", "_hi")
)
"""Each metric followed by its bootstrap interval (``_lo``, ``_hi``)."""
SUMMARY_COLUMNS: tuple[str, ...] = (
    "method",
    "trials",
    "diverged",
    *INTERVAL_COLUMNS,
    *NEES_COLUMNS,
    "runtime_s",
)
"""summary.csv: the metrics with their intervals, the NEES judgement of the method's own
covariance (empty for a method that reports none), and the run time."""
BAND_COLUMNS: tuple[str, ...] = ("method", "t_s", "group", "rms", "lo", "hi")
NEES_FILE_COLUMNS: tuple[str, ...] = ("method", "t_s", "nees", "trials", "band_lo", "band_hi")
LINESTYLES: tuple[Any, ...] = ("-", "--", "-.", ":", (0, (5, 1)), (0, (3, 1, 1, 1)))
"""Methods that coincide (``kf-tuned`` picking κ = 1 is ``kf``) stay visible: each method has
its own dash pattern and marker as well as its colour."""
MARKERS: tuple[str, ...] = ("o", "s", "^", "v", "D", "P", "X", "*", "h", "<", ">")

TRIAL_COLUMNS: tuple[str, ...] = ("method", "trial", *METRIC_COLUMNS)
PAIRED_COLUMNS: tuple[str, ...] = (
    "method", "baseline", "metric", "ratio", "lo", "hi",
    "median_ratio", "median_lo", "median_hi", "p_improve", "worst_decile", "verdict",
)  # fmt: skip
"""paired.csv: the pooled RMS ratio and its paired interval (docs/architecture.md), then the
per-trial comparison (median ratio and interval, P(improve), worst decile) and the verdict
(docs/methods.md, "Per-trial verdicts")."""
UNITS = {"att_arcsec": "arcsec", "bias_degph": "deg/h", "sf_ppm": "ppm", "ma_urad": "µrad"}


def crlb_csv_text(result: CrlbResult) -> str:
    """``t_s`` plus the 15 one-sigma bounds in display units (docs/architecture.md)."""
    disp = result.bound / DISPLAY_UNIT
    return csv_text(
        ("t_s", *STATE_COLUMNS),
        ([float(t), *map(float, row)] for t, row in zip(result.t, disp, strict=True)),
    )


def write_crlb_csv(path: str | Path, result: CrlbResult) -> None:
    """Write :func:`crlb_csv_text` to ``path`` atomically."""
    atomic_write_bytes(path, crlb_csv_text(result).encode())


def method_style(index: int, n_points: int) -> dict[str, Any]:
    """Line style of the ``index``-th method: colour, dash pattern and sparse markers."""
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    return {
        "color": colors[index % len(colors)],
        "ls": LINESTYLES[index % len(LINESTYLES)],
        "marker": MARKERS[index % len(MARKERS)],
        "markevery": (index * max(1, n_points // 60), max(1, n_points // 12)),
        "markersize": 4,
        "markerfacecolor": "none",
    }


def mark_events(ax: Any, cfg: Config) -> None:
    """Shade the maneuvers and draw the calibration jumps of the config's (nominal) schedule."""
    sc = cfg.scenario
    drawn = sc.random_events
    if drawn is None or drawn.maneuvers is None:
        for mv in sc.maneuvers:
            ax.axvspan(mv.start_s, mv.start_s + mv.duration_s, color="0.85", lw=0, zorder=0)
    if drawn is None or drawn.jump is None:
        for j in sc.calibration_jumps:
            ax.axvline(j.t_s, color="k", ls=":", lw=1.0, zorder=1)


def events_caption(cfg: Config) -> str:
    """What the marks of :func:`mark_events` are (and which events are drawn per trial)."""
    drawn = cfg.scenario.random_events
    parts = []
    if drawn is None or drawn.maneuvers is None:
        parts.append("grey: maneuvers")
    if cfg.scenario.calibration_jumps and (drawn is None or drawn.jump is None):
        parts.append("dotted: calibration jump")
    if drawn is not None:
        parts.append("events drawn per trial are not marked")
    return "; ".join(parts)


def shared_legend(fig: Figure, axes: Any, ncol: int = 6) -> None:
    """One legend for the whole figure, below the panels (outside every axes, so it never
    hides data however many methods there are); the entries of every panel, once each."""
    entries: dict[str, Any] = {}
    for ax in np.ravel(axes):
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            entries.setdefault(label, handle)
    if entries:
        fig.legend(entries.values(), entries.keys(), loc="outside lower center",
                   ncol=min(ncol, len(entries)), fontsize=8, frameon=False)  # fmt: skip


PLOT_POINTS = 20_000
"""Most epochs a time plot draws per curve; longer runs (a recorded day at 10 Hz) are drawn at
every k-th epoch, the last included (the files keep every epoch)."""


def plot_epochs(n: int) -> np.ndarray:
    """The epochs a time plot draws: all of them up to :data:`PLOT_POINTS`."""
    step = -(-n // PLOT_POINTS)
    return np.arange(n) if step == 1 else np.unique(np.append(np.arange(0, n, step), n - 1))


def rms_groups_figure(res: BenchResult) -> Figure:
    """RMS over trials vs time per state group for every method, with its bootstrap band, the
    CRLB, the maneuvers and the calibration jumps; one shared legend below the panels."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), sharex=True, layout="constrained")
    pick = plot_epochs(res.t.size)
    t = res.t[pick]
    bound_ms = (res.bound.bound[pick] / DISPLAY_UNIT) ** 2
    crlb_groups = group_rms(bound_ms)
    level = 100 * res.config.run.bootstrap.level
    for gi, (ax, (g, title)) in enumerate(zip(axes.ravel(), GROUP_TITLES.items(), strict=True)):
        mark_events(ax, res.config)
        for i, m in enumerate(res.methods):
            style = method_style(i, t.size)
            ax.semilogy(t, group_rms((m.rms[pick] / DISPLAY_UNIT) ** 2)[g], label=m.name, lw=1.2,
                        **style)  # fmt: skip
            if m.band is not None and res.band_t.size:
                lo, hi = m.band[:, gi, 1], m.band[:, gi, 2]
                ax.fill_between(res.band_t, lo, hi, color=style["color"], alpha=0.18, lw=0)
        ax.semilogy(t, crlb_groups[g], "k--", lw=1.0, label="CRLB (1σ)")
        ax.set_title(title)
        ax.set_ylabel(f"RMS [{UNITS[g]}]")
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    shared_legend(fig, axes)
    caption = events_caption(res.config)
    fig.suptitle(
        f"{res.config.name}: RMS over {res.trials} trials (seed {res.seed}); bands: {level:g} % "
        f"bootstrap over trials" + (f"; {caption}" if caption else "")
    )
    return fig


def rms_groups_png(res: BenchResult) -> bytes:
    """:func:`rms_groups_figure` as PNG bytes."""
    return figure_png(rms_groups_figure(res))


def nees_figure(res: BenchResult) -> Figure | None:
    """Trial-averaged NEES / 15 vs time for every method that reports a covariance, with the
    χ² band of the average (None: no method reports one)."""
    judged = [(i, m) for i, m in enumerate(res.methods) if m.nees is not None]
    if not judged or res.nees_t.size == 0:
        return None
    fig, ax = plt.subplots(figsize=(10, 5.4), layout="constrained")
    mark_events(ax, res.config)
    for i, m in judged:
        assert m.nees is not None
        ax.semilogy(res.nees_t, m.nees / 15.0, lw=1.2, label=m.name,
                    **method_style(i, res.nees_t.size))  # fmt: skip
    lo, hi = nees_band(judged[0][1], res.config.run.bootstrap.level)
    ax.fill_between(res.nees_t, lo / 15.0, hi / 15.0, color="gold", alpha=0.35, lw=0,
                    label="χ² band (consistent)")  # fmt: skip
    if res.nees_t[-1] >= res.config.run.settled_s:  # a run shorter than settled_s has no start
        ax.axvline(res.config.run.settled_s, color="0.4", lw=0.8, ls="--")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("trial-averaged NEES / 15")
    ax.set_title(f"{res.config.name}: each method's covariance against its errors\n"
                 f"(1 = consistent; judged {nees_window_text(res)})", fontsize=10)  # fmt: skip
    ax.grid(True, which="both", alpha=0.3)
    shared_legend(fig, [ax])
    return fig


def nees_png(res: BenchResult) -> bytes | None:
    """:func:`nees_figure` as PNG bytes (None: no method reports a covariance)."""
    fig = nees_figure(res)
    return None if fig is None else figure_png(fig)


def nees_band(m: MethodResult, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The two-sided χ² band of a trial-averaged NEES of 15 states over ``n`` trials."""
    assert m.nees_trials is not None
    return average_nees_band(15, np.maximum(m.nees_trials, 1), level)


def band_rows(res: BenchResult) -> list[list[object]]:
    """rms_bands.csv: per method, band epoch and group: the RMS and its bootstrap band."""
    rows: list[list[object]] = []
    for m in res.methods:
        if m.band is None:
            continue
        for k, t in enumerate(res.band_t):
            rows += [[m.name, float(t), g, *map(float, m.band[k, gi])]
                     for gi, g in enumerate(GROUP_TITLES)]  # fmt: skip
    return rows


def nees_rows(res: BenchResult) -> list[list[object]]:
    """nees.csv: per method and sampled epoch, the trial-averaged NEES and its χ² band."""
    rows: list[list[object]] = []
    level = res.config.run.bootstrap.level
    for m in res.methods:
        if m.nees is None or m.nees_trials is None:
            continue
        lo, hi = nees_band(m, level)
        rows += [
            [m.name, float(t), float(v), int(c), float(a), float(b)]
            for t, v, c, a, b in zip(res.nees_t, m.nees, m.nees_trials, lo, hi, strict=True)
        ]
    return rows


_STATE_GROUP_NAMES = {
    "att": "attitude",
    "bias": "gyro bias",
    "sf": "scale factor s",
    "ma": "misalignment k",
}


def state_title(column: str) -> str:
    """A reader's name for a state column: ``att_x_arcsec`` → "attitude x", ``sf_y_ppm`` →
    "scale factor s_y", ``ma_xy_urad`` → "misalignment k_xy"."""
    group, axis = column.split("_")[:2]
    name = _STATE_GROUP_NAMES[group]
    return f"{name}_{axis}" if name.endswith((" s", " k")) else f"{name} {axis}"


def state_unit(column: str) -> str:
    """The display unit of a state column (``ma_xy_urad`` → µrad)."""
    group = column.split("_")[0]
    return next(u for g, u in UNITS.items() if g.split("_")[0] == group)


def rms_states_figure(res: BenchResult) -> Figure:
    """RMS over trials vs time for each of the 15 states, with the CRLB: one row per group
    (misalignment: two), a title per state, axis labels with units, one shared legend."""
    fig, axes = plt.subplots(5, 3, figsize=(13, 15), sharex=True, layout="constrained")
    pick = plot_epochs(res.t.size)
    t = res.t[pick]
    bound = res.bound.bound[pick] / DISPLAY_UNIT
    for i, ax in enumerate(axes.ravel()):
        mark_events(ax, res.config)
        for j, m in enumerate(res.methods):
            ax.semilogy(t, m.rms[pick, i] / DISPLAY_UNIT[i], lw=1.0, label=m.name,
                        **method_style(j, t.size))  # fmt: skip
        ax.semilogy(t, bound[:, i], "k--", lw=0.8, label="CRLB (1σ)")
        ax.set_title(state_title(STATE_COLUMNS[i]), fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        if i % 3 == 0:
            ax.set_ylabel(f"RMS [{state_unit(STATE_COLUMNS[i])}]")
        if i >= 12:
            ax.set_xlabel("time [s]")
    shared_legend(fig, axes)
    caption = events_caption(res.config)
    fig.suptitle(f"{res.config.name}: RMS over {res.trials} trials per state"
                 + (f"; {caption}" if caption else ""))  # fmt: skip
    return fig


def rms_states_png(res: BenchResult) -> bytes:
    """:func:`rms_states_figure` as PNG bytes."""
    return figure_png(rms_states_figure(res))


def kappa_figure(res: BenchResult) -> Figure | None:
    """κ chosen over time by each adaptive method, one small panel each (shared axes): the
    median over trials and its 10–90 % band. Separate panels, because overlaid bands of many
    methods merge into one wash. None: no method chose κ."""
    traced = [(i, m) for i, m in enumerate(res.methods) if m.kappa is not None]
    if not traced:
        return None
    ncols = 1 if len(traced) <= 2 else 2
    nrows = -(-len(traced) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(6.0 * ncols, 1.2 + 2.1 * nrows),
                             sharex=True, sharey=True, squeeze=False,
                             layout="constrained")  # fmt: skip
    acts = res.config.adaptive.actions.values()
    for ax, (i, m) in zip(axes.ravel(), traced, strict=False):
        assert m.kappa is not None
        mark_events(ax, res.config)
        lo, med, hi = np.percentile(m.kappa, [10, 50, 90], axis=0)
        color = method_style(i, res.kappa_t.size)["color"]
        ax.fill_between(res.kappa_t, lo, hi, color=color, alpha=0.25, lw=0, step="post")
        ax.step(res.kappa_t, med, where="post", lw=1.3, color=color)
        ax.axhline(1.0, color="0.3", lw=0.7, ls=":")
        ax.set_yscale("log")
        ax.set_ylim(min(acts) / 1.5, max(acts) * 1.5)
        ax.set_title(m.name, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes.ravel()[len(traced) :]:
        ax.set_visible(False)
    for ax in axes[:, 0]:
        ax.set_ylabel("κ")
    for col in range(ncols):  # the lowest visible panel of each column carries the time axis
        shown = [ax for ax in axes[:, col] if ax.get_visible()]
        if shown:
            shown[-1].set_xlabel("time [s]")
            shown[-1].xaxis.set_tick_params(labelbottom=True)
    caption = events_caption(res.config)
    fig.suptitle(
        f"{res.config.name}: process-noise factor κ in use (q_p = κ · q_p0), per method: median "
        f"over {res.trials} trials (line) and 10–90 % of trials (band); horizontal dotted: κ = 1"
        + (f"\n{caption}" if caption else ""),
        fontsize=10,
    )
    return fig


def kappa_png(res: BenchResult) -> bytes | None:
    """:func:`kappa_figure` as PNG bytes (None: no method chose κ)."""
    fig = kappa_figure(res)
    return None if fig is None else figure_png(fig)


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
        [
            m.name,
            m.trials,
            m.diverged,
            *(m.summary[c] for c in INTERVAL_COLUMNS),
            *(_blank_nan(m.summary.get(c, float("nan"))) for c in NEES_COLUMNS),
            round(m.runtime_s, 3),
        ]
        for m in res.methods
    ]


def _blank_nan(v: float) -> object:
    return "" if np.isnan(v) else v


def trial_rows(res: BenchResult) -> list[list[object]]:
    """trials.csv: every metric of every trial, per method (display units)."""
    rows: list[list[object]] = []
    for m in res.methods:
        if m.trial_values is None:
            continue
        rows += [[m.name, i, *map(float, v)] for i, v in enumerate(m.trial_values)]
    return rows


def paired_rows(res: BenchResult) -> list[list[object]]:
    return [
        [p.method, p.baseline, p.metric, p.ratio, p.lo, p.hi, p.median, p.median_lo,
         p.median_hi, p.p_improve, p.worst_decile, p.verdict]
        for p in res.paired
    ]  # fmt: skip


def too_few_text(trials: int, level: float) -> str:
    """Why a table carries no verdict marks with ``trials`` trials at ``level`` (empty when it
    has enough: :func:`~qkf.core.stats.min_verdict_trials`)."""
    need = min_verdict_trials(level)
    if trials >= need:
        return ""
    return (
        f"No verdict marks: {trials} trial(s), fewer than the {need} a verdict needs at "
        f"{100 * level:g} % (with fewer, the bootstrap interval of the median per-trial ratio "
        "misses the true median more than twice as often as it should; docs/methods.md, "
        '"Per-trial verdicts"). The numbers are printed for information only.'
    )


def per_trial_lines(res: BenchResult, metric: str = "state_settled") -> list[str]:
    """The per-trial table of summary.md: each method against each baseline on ``metric``."""
    rows = [p for p in res.paired if p.metric == metric]
    if not rows:
        return []
    level = 100 * res.config.run.bootstrap.level
    lines = [
        "",
        f"Against the baselines on `{metric}`, pooled and per trial (paired {level:g} % "
        "intervals over the same resamples; P(improve) = share of trials with a ratio below "
        "1; worst decile = 90th percentile of the per-trial ratios; *better* / *worse* needs "
        "both intervals below / above 1):",
        "",
        "| method | baseline | pooled ratio | median ratio | P(improve) | worst decile | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in rows:
        lines.append(
            f"| {p.method} | {p.baseline} | {p.ratio:.3f} [{p.lo:.3f}, {p.hi:.3f}] | "
            f"{p.median:.3f} [{p.median_lo:.3f}, {p.median_hi:.3f}] | {p.p_improve:.0%} | "
            f"{p.worst_decile:.3f} | {p.verdict} |"
        )
    return lines


def _recovery(res: BenchResult) -> dict[str, dict[str, float]]:
    jumps = res.config.scenario.calibration_jumps
    events = res.config.scenario.random_events
    if not jumps or (events is not None and events.jump is not None):
        return {}  # no jump, or one at a different time in every trial
    jump = min(j.t_s for j in jumps)
    return {
        m.name: recovery_times(m.rms, res.t, jump, res.config.run.settled_s) for m in res.methods
    }


def settled_window_text(t: np.ndarray, settled_s: float, settle_factor: float | None = None) -> str:
    """What the *settled* window really is for epochs ``t`` (s): with ``settle_factor`` (each
    trial's own window, :mod:`qkf.transfer_alignment.settled`) how it opens; else "from 400 s
    on"; for a run that ends before ``settled_s``, the last epoch alone (which is what the
    metrics then average over)."""
    if t.size == 0 or t[-1] >= settled_s - 1e-9:
        if settle_factor is not None:
            return (
                f"each trial's own window, from the later of {settled_s:g} s and the first "
                "epoch after its opening rotations at which its own CRLB of every calibration "
                f"term is within {settle_factor:g} × its end-of-run value (docs/methods.md, "
                '"The settled window"); state settled is in units of that trial\'s own '
                "end-of-run CRLB"
            )
        return f"from {settled_s:g} s on"
    return (
        f"the last epoch only (t = {t[-1]:g} s), because the run ends before run.settled_s = "
        f"{settled_s:g} s: the settled values are the errors at that one epoch, not an average "
        "over a settled stretch"
    )


def nees_window_text(res: BenchResult) -> str:
    """Where NEES is judged: "from 400 s on", or the last sampled epoch alone when the run ends
    before ``run.settled_s`` (what :func:`~qkf.transfer_alignment.benchmark.nees_summary`
    then uses)."""
    settled_s = res.config.run.settled_s
    t = res.nees_t
    if t.size == 0 or t[-1] >= settled_s - 1e-9:
        return f"from {settled_s:g} s on"
    return (
        f"at the last sampled epoch only (t = {t[-1]:g} s; the run ends before "
        f"run.settled_s = {settled_s:g} s)"
    )


def summary_markdown(res: BenchResult, trial_names: Sequence[str] | None = None) -> str:
    """summary.md of a benchmark; ``trial_names[trial]``: what each trial is (recorded files)."""
    cfg = res.config
    weights = state_weights(cfg) if res.weights is None else res.weights
    crlb_summary = summarize(
        res.bound.bound / DISPLAY_UNIT, res.t, cfg.run.settled_s, weights / DISPLAY_UNIT
    )
    verdicts = {(p.method, p.metric): p.verdict for p in res.paired if p.baseline == "kf"}
    own = cfg.run.settle_factor if res.weights is None else None  # recorded: fixed window
    head = ["method", "trials"]
    for g in GROUP_TITLES:
        head += [f"{g.split('_')[0]} {w} [{UNITS[g]}]" for w in WINDOWS]
    head += ["state settled [× CRLB]", "runtime [s]"]
    mark = {"better": " ↓", "worse": " ↑", "inconclusive": "", "unjudged": ""}
    level = 100 * cfg.run.bootstrap.level
    lines = [
        f"# qkf bench: {cfg.name}",
        "",
        f"{cfg.description}".strip(),
        "",
        *divergence_lines([d for m in res.methods for d in m.divergences], trial_names),
        f"Trials: {res.trials}, seed: {res.seed}, matching: {cfg.filter.matching}, "
        f"q_p0 = {cfg.filter.qp0:g} /s, duration {cfg.scenario.duration_s:g} s.",
        "RMS over trials; *final* = over the last 20 % of the run, *avg* = over the whole run, "
        f"*settled* = {settled_window_text(res.t, cfg.run.settled_s, own)}; a group's RMS is the "
        "root of the mean square over its components. Intervals of every value are in "
        f"summary.csv ({level:g} % bootstrap over trials).",
    ]
    few = too_few_text(res.trials, cfg.run.bootstrap.level)
    if verdicts and few:
        lines.append(few)
    elif verdicts:
        lines.append(
            f"↓ / ↑: lower / higher than `kf`, pooled and per trial (the paired {level:g} % "
            "intervals of the pooled RMS ratio and of the median per-trial ratio both below / "
            "above 1; paired.csv)."
        )
    lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m in res.methods:
        vals = [
            f"{m.summary[c]:.4g}{mark[verdicts.get((m.name, c), 'inconclusive')]}"
            for c in METRIC_COLUMNS
        ]
        lines.append(f"| {m.name} | {m.trials} | " + " | ".join(vals) + f" | {m.runtime_s:.2f} |")
    vals = [f"{crlb_summary[c]:.4g}" for c in METRIC_COLUMNS]
    if any(np.isfinite(crlb_summary[c]) for c in METRIC_COLUMNS):  # recorded runs have none
        lines.append("| CRLB (1σ) | – | " + " | ".join(vals) + " | – |")
    lines += per_trial_lines(res)
    judged = [m for m in res.methods if not np.isnan(m.summary.get("nees_mean", np.nan))]
    if judged:
        lines += [
            "",
            f"Consistency of each method's own covariance, {nees_window_text(res)} "
            f"(sampled every {cfg.run.nees_every_s:g} s): trial-averaged NEES / 15 (1 = "
            f"consistent, > 1 over-confident) and the fraction of sampled epochs inside the "
            f"{level:g} % χ² band (nees.csv, nees.png):",
            "",
            "| method | NEES / 15 | inside band |",
            "|---|---|---|",
            *(
                f"| {m.name} | {m.summary['nees_mean']:.3g} | {m.summary['nees_in_band']:.0%} |"
                for m in judged
            ),
        ]
    lines += _gap_lines(res)
    recovery = _recovery(res)
    if recovery:
        jump = min(j.t_s for j in cfg.scenario.calibration_jumps)
        why = (
            f"; every cell is – here: the jump at {jump:g} s comes before run.settled_s = "
            f"{cfg.run.settled_s:g} s, so there is no settled pre-jump level"
            if jump <= cfg.run.settled_s + 1e-9
            else ""
        )
        lines += [
            "",
            "Recovery after the calibration jump (s until the group RMS is back within 1.5× its "
            f"settled pre-jump level; – = not within the run{why}):",
            "",
            "| method | " + " | ".join(GROUP_TITLES) + " |",
            "|" + "---|" * (len(GROUP_TITLES) + 1),
        ]
        for name, rec in recovery.items():
            cells = ["–" if np.isnan(v) else f"{v:g}" for v in rec.values()]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    if cfg.scenario.random_events is not None:
        lines += [
            "",
            "Events are drawn per trial (a randomized family): the CRLB row is the bound along "
            "the nominal schedule of the config, a reference, not each trial's bound.",
        ]
    notes = [f"- {m.name}: {note}" for m in res.methods for note in m.notes.values()]
    if notes:
        lines += ["", *notes]
    return "\n".join(lines) + "\n"


def _gap_lines(res: BenchResult) -> list[str]:
    """With both ``kf`` and ``oracle`` in the run: each method's share of the settled-window gap
    between them, ``(kf − method) / (kf − oracle)`` (1 = as good as the oracle)."""
    by_name = {m.name: m for m in res.methods}
    if "kf" not in by_name or "oracle" not in by_name:
        return []
    cols = [f"{g}_settled" for g in GROUP_TITLES]
    kf, oracle = by_name["kf"].summary, by_name["oracle"].summary
    out = [
        "",
        "Share of the gap between `kf` and the `oracle` schedule closed, settled window "
        "(`(kf − method) / (kf − oracle)`; 1 = as good as the oracle, < 0 = worse than kf; – "
        "where the oracle is not better than kf):",
        "",
        "| method | " + " | ".join(cols) + " |",
        "|" + "---|" * (len(cols) + 1),
    ]
    for m in res.methods:
        if m.name in ("kf", "oracle"):
            continue
        cells = []
        for c in cols:
            gap = kf[c] - oracle[c]
            cells.append(f"{(kf[c] - m.summary[c]) / gap:.2f}" if gap > 0 else "–")
        out.append(f"| {m.name} | " + " | ".join(cells) + " |")
    return out


def bench_tables(
    res: BenchResult, per_epoch: bool = True, trial_names: Sequence[str] | None = None
) -> dict[str, bytes]:
    """The text files of a benchmark, rendered: rms.csv, summary.csv, summary.md, crlb.csv and
    (if any method chose κ) kappa.csv. ``per_epoch`` False leaves out the two files with a row
    per epoch (rms.csv, crlb.csv), for a caller that streams them (a long recorded run);
    ``trial_names``: see :func:`summary_markdown`."""
    files = {}
    if per_epoch:
        rms_rows = [
            [m.name, float(t), *map(float, row)]
            for m in res.methods
            for t, row in zip(res.t, m.rms / DISPLAY_UNIT, strict=True)
        ]
        files["rms.csv"] = csv_text(RMS_COLUMNS, rms_rows)
    files |= {
        "summary.csv": csv_text(SUMMARY_COLUMNS, summary_rows(res)),
        "trials.csv": csv_text(TRIAL_COLUMNS, trial_rows(res)),
        "summary.md": summary_markdown(res, trial_names),
    }
    if per_epoch:
        files["crlb.csv"] = crlb_csv_text(res.bound)
    if res.paired:
        files["paired.csv"] = csv_text(PAIRED_COLUMNS, paired_rows(res))
    if any(m.band is not None for m in res.methods):
        files["rms_bands.csv"] = csv_text(BAND_COLUMNS, band_rows(res))
    if any(m.nees is not None for m in res.methods):
        files["nees.csv"] = csv_text(NEES_FILE_COLUMNS, nees_rows(res))
    if any(m.kappa is not None for m in res.methods):
        files["kappa.csv"] = csv_text(("method", "trial", "t_s", "kappa"), kappa_rows(res))
    return {name: text.encode() for name, text in files.items()}


RMS_COLUMNS: tuple[str, ...] = ("method", "t_s", *STATE_COLUMNS)
"""rms.csv: per method and epoch, the RMS over trials of each state's error (display units)."""


def bench_figures(res: BenchResult) -> dict[str, bytes]:
    """The figures of a benchmark as PNG bytes."""
    figs = {"rms_groups.png": rms_groups_png(res), "rms_states.png": rms_states_png(res)}
    for name, png in (("kappa.png", kappa_png(res)), ("nees.png", nees_png(res))):
        if png is not None:
            figs[name] = png
    return figs


def bench_manifest(res: BenchResult, command: list[str] | None = None) -> dict[str, Any]:
    """``run.json`` of a benchmark (docs/architecture.md, "Output files")."""
    return manifest(
        "bench",
        res.config.model_dump(mode="json"),
        command,
        methods=[{"name": m.name, "spec": m.spec} for m in res.methods],
        trials=res.trials,
        seed=res.seed,
        backend=res.backend,
        workers=res.workers,
        cache=res.cache,
    )


def write_bench(
    res: BenchResult, out_dir: str | Path, command: list[str] | None = None
) -> list[Path]:
    """Write the files of a benchmark into ``out_dir``, replacing any earlier run there whole.

    Everything is rendered in memory first, written into a staging directory beside
    ``out_dir`` and swapped in when complete (:func:`qkf.core.io.staged_directory`).
    """
    files = {**bench_tables(res), **bench_figures(res)}
    out = Path(out_dir)
    with staged_directory(out) as stage:
        for name, content in files.items():
            atomic_write_bytes(stage / name, content)
        write_manifest(stage, bench_manifest(res, command))
    return [out / name for name in (*files, "run.json")]


@dataclass(frozen=True)
class _Row:
    """One data row of a result CSV read back, with where it came from (for messages)."""

    path: Path
    line: int  # 1-based line of the file (the header is line 1)
    cells: dict[str, str]

    def text(self, col: str) -> str:
        return self.cells[col]

    def num(self, col: str, blank: float | None = None) -> float:
        """The cell as a number; ``blank``: the value of an empty cell (else it is an error)."""
        raw = self.cells[col]
        if raw == "" and blank is not None:
            return blank
        try:
            return float(raw)
        except ValueError:
            raise ConfigError(
                f"{self.path}: line {self.line}: {col}: {raw!r} is not a number "
                "(a truncated or corrupt file?)"
            ) from None

    def integer(self, col: str) -> int:
        value = self.num(col)
        if not value.is_integer():
            raise ConfigError(f"{self.path}: line {self.line}: {col}: {value:g} is not an integer")
        return int(value)


def checked_rows(
    path: Path, what: str, header_problem: Callable[[list[str]], str | None]
) -> Iterator[tuple[list[str], int, list[str]]]:
    """``(header, line, cells)`` for each data row of a CSV file qkf wrote, every row as long
    as the header. ``ConfigError`` naming the file (and the line) for a missing file, a header
    ``header_problem`` refuses (it returns the message, or None), a row with too few or too
    many cells (a truncated file), bad bytes or broken CSV; ``what`` names the folder the file
    belongs to in the messages (``qkf bench folder``)."""
    if not path.is_file():
        raise ConfigError(f"{path}: missing (not a complete {what})")
    try:
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None) or []
            problem = header_problem(header)
            if problem is not None:
                raise ConfigError(f"{path}: {problem}")
            for cells in reader:
                if len(cells) != len(header):
                    raise ConfigError(
                        f"{path}: line {reader.line_num}: {len(cells)} cells where the header "
                        f"has {len(header)} (a truncated or corrupt file?)"
                    )
                yield header, reader.line_num, cells
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file (a corrupt file?)") from None
    except csv.Error as exc:
        raise ConfigError(f"{path}: not a readable CSV file ({exc})") from None


def _read_rows(path: Path, columns: tuple[str, ...] = ()) -> list[_Row]:
    """The data rows of a result CSV, checked (:func:`checked_rows`): a missing column is an
    error too."""

    def header_problem(header: list[str]) -> str | None:
        if not header:
            return "empty (not a complete qkf bench folder)"
        missing = [c for c in columns if c not in header]
        return f"line 1: no column {', '.join(missing)}" if missing else None

    rows = checked_rows(path, "qkf bench folder", header_problem)
    return [_Row(path, line, dict(zip(header, cells, strict=True))) for header, line, cells in rows]


def read_trials_csv(folder: str | Path) -> dict[str, np.ndarray]:
    """``trials.csv`` of a bench folder read back: per method, the per-trial metric values
    (trials, K) in :data:`METRIC_COLUMNS` order, rows in trial order. ``ConfigError`` names the
    file and line of anything that cannot be read."""
    path = Path(folder) / "trials.csv"
    per: dict[str, list[tuple[int, list[float]]]] = defaultdict(list)
    for r in _read_rows(path, TRIAL_COLUMNS):
        per[r.text("method")].append((r.integer("trial"), [r.num(c) for c in METRIC_COLUMNS]))
    return {m: np.array([v for _, v in sorted(rows)]) for m, rows in per.items()}


def read_crlb_csv(path: str | Path) -> CrlbResult:
    """A ``crlb.csv`` read back (SI), its covariance left empty; ``ConfigError`` names the file
    and the line of a bad row."""
    rows = _read_rows(Path(path), ("t_s", *STATE_COLUMNS))
    if not rows:
        raise ConfigError(f"{path}: no rows (a truncated file?)")
    t = np.array([r.num("t_s") for r in rows])
    bound = np.array([[r.num(c) for c in STATE_COLUMNS] for r in rows]) * DISPLAY_UNIT
    return CrlbResult(t=t, bound=bound, cov=np.empty((0, 15, 15)))


def load_bench(folder: str | Path) -> BenchResult:
    """A finished benchmark read back from its files (``run.json``, ``rms.csv``, ``crlb.csv``,
    ``summary.csv``, ``kappa.csv``), for redrawing its figures. ``ConfigError`` names the file
    and the line of anything that cannot be read (a truncated or corrupt file)."""
    folder = Path(folder)
    info = read_manifest(folder, "bench")
    cfg = validate(Config, info["config"], str(folder / "run.json"), "configuration")
    unit = DISPLAY_UNIT
    bound = read_crlb_csv(folder / "crlb.csv")
    t = bound.t
    per_method: dict[str, list[list[float]]] = defaultdict(list)
    rms_path = folder / "rms.csv"
    for r in _read_rows(rms_path, ("method", *STATE_COLUMNS)):
        per_method[r.text("method")].append([r.num(c) for c in STATE_COLUMNS])
    kappa: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    kappa_t: list[float] = []
    if (folder / "kappa.csv").is_file():
        for r in _read_rows(folder / "kappa.csv", ("method", "trial", "t_s", "kappa")):
            kappa[r.text("method")][r.integer("trial")].append(r.num("kappa"))
            if not kappa_t or r.num("t_s") > kappa_t[-1]:
                kappa_t.append(r.num("t_s"))
    bands, band_t = _read_bands(folder / "rms_bands.csv")
    nees, nees_t = _read_nees(folder / "nees.csv")
    methods = []
    summary_cols = ("method", "trials", "diverged", "runtime_s", *INTERVAL_COLUMNS)
    for r in _read_rows(folder / "summary.csv", summary_cols):
        name = r.text("method")
        # a short method (rows lost at the end of rms.csv) would plot a curve that stops early
        if len(per_method.get(name, [])) != t.size:
            raise ConfigError(
                f"{rms_path}: method {name}: {len(per_method.get(name, []))} rows where crlb.csv "
                f"has {t.size} epochs (a truncated file?)"
            )
        traces = kappa.get(name)
        if traces and len({len(v) for v in traces.values()} | {len(kappa_t)}) > 1:
            raise ConfigError(f"{folder / 'kappa.csv'}: method {name}: traces of unequal length "
                              "(a truncated file?)")  # fmt: skip
        methods.append(
            MethodResult(
                name=name,
                rms=np.array(per_method[name]) * unit,
                trials=r.integer("trials"),
                diverged=r.integer("diverged"),
                runtime_s=r.num("runtime_s"),
                summary={
                    c: r.num(c, blank=float("nan")) if c in r.cells else float("nan")
                    for c in (*INTERVAL_COLUMNS, *NEES_COLUMNS)
                },
                kappa=np.array([traces[i] for i in sorted(traces)]) if traces else None,
                band=bands.get(name),
                nees=nees.get(name, (None, None))[0],
                nees_trials=nees.get(name, (None, None))[1],
            )
        )
    return BenchResult(
        config=cfg,
        seed=int(info["seed"]),
        trials=int(info["trials"]),
        t=t,
        methods=methods,
        bound=bound,
        kappa_t=np.array(kappa_t),
        backend=str(info.get("backend", "local")),
        workers=int(info.get("workers", 1)),
        band_t=band_t,
        nees_t=nees_t,
    )


def _read_bands(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """rms_bands.csv back as (T, groups, 3) per method (absent file: no bands)."""
    if not path.is_file():
        return {}, np.empty(0)
    rows = _read_rows(path, BAND_COLUMNS)
    groups = list(GROUP_TITLES)
    t = np.unique([r.num("t_s") for r in rows])
    out: dict[str, np.ndarray] = {}
    for r in rows:
        if r.text("group") not in groups:
            raise ConfigError(f"{path}: line {r.line}: group: {r.text('group')!r} is not one of "
                              f"{', '.join(groups)}")  # fmt: skip
        band = out.setdefault(r.text("method"), np.full((t.size, len(groups), 3), np.nan))
        k = int(np.searchsorted(t, r.num("t_s")))
        band[k, groups.index(r.text("group"))] = [r.num("rms"), r.num("lo"), r.num("hi")]
    return out, t


def _read_nees(path: Path) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """nees.csv back as (NEES, trials) per method (absent file: none)."""
    if not path.is_file():
        return {}, np.empty(0)
    per: dict[str, list[tuple[float, float, int]]] = defaultdict(list)
    for r in _read_rows(path, NEES_FILE_COLUMNS):
        per[r.text("method")].append((r.num("t_s"), r.num("nees"), r.integer("trials")))
    if len({len(v) for v in per.values()}) > 1:
        raise ConfigError(f"{path}: methods with unequal numbers of rows (a truncated file?)")
    out = {
        m: (np.array([v[1] for v in vals]), np.array([v[2] for v in vals]))
        for m, vals in per.items()
    }
    t = np.array([v[0] for v in next(iter(per.values()))]) if per else np.empty(0)
    return out, t


def redraw_bench(*folders: str | Path) -> list[Path]:
    """Redraw every figure of finished benchmarks (a sweep's folders, say) from their files;
    returns the figures. Every folder is read and rendered before the first file is written,
    so a truncated or corrupt file (``ConfigError``) leaves every figure as it was."""
    rendered = [(Path(f), bench_figures(load_bench(f))) for f in folders]
    written = []
    for folder, figures in rendered:
        for name, content in figures.items():
            atomic_write_bytes(folder / name, content)
            written.append(folder / name)
    return written


__all__ = [
    "METRIC_COLUMNS",
    "PAIRED_COLUMNS",
    "SUMMARY_COLUMNS",
    "TRIAL_COLUMNS",
    "load_bench",
    "read_crlb_csv",
    "read_trials_csv",
    "redraw_bench",
    "rms_groups_png",
    "summary_markdown",
    "write_bench",
    "write_crlb_csv",
]
