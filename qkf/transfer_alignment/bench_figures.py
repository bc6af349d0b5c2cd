"""The figures of a transfer-alignment bench (``rms_groups.png``, ``rms_states.png``,
``nees.png``, ``kappa.png``) and the plotting conventions the study and family figures share
(one style per method, the scenario's events marked, one legend outside the data)."""

from __future__ import annotations

from typing import Any

import numpy as np

from qkf.core.plotting import Figure, figure_png, plt
from qkf.transfer_alignment.benchmark import BenchResult
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.metrics import group_rms
from qkf.transfer_alignment.report import UNITS, nees_band, nees_window_text
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES, STATE_COLUMNS

LINESTYLES: tuple[Any, ...] = ("-", "--", "-.", ":", (0, (5, 1)), (0, (3, 1, 1, 1)))
"""Methods that coincide (``kf-tuned`` picking κ = 1 is ``kf``) stay visible: each method has
its own dash pattern and marker as well as its colour."""


MARKERS: tuple[str, ...] = ("o", "s", "^", "v", "D", "P", "X", "*", "h", "<", ">")


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


def bench_figures(res: BenchResult) -> dict[str, bytes]:
    """The figures of a benchmark as PNG bytes."""
    figs = {"rms_groups.png": rms_groups_png(res), "rms_states.png": rms_states_png(res)}
    for name, png in (("kappa.png", kappa_png(res)), ("nees.png", nees_png(res))):
        if png is not None:
            figs[name] = png
    return figs


__all__ = [
    "bench_figures",
    "events_caption",
    "mark_events",
    "method_style",
    "rms_groups_png",
    "shared_legend",
    "state_title",
    "state_unit",
]
