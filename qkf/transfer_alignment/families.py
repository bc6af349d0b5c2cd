r"""The family table: every method judged on every scenario family, against ``kf-tuned``.

``qkf study families`` runs each family (a randomized preset, docs/models.md "Scenario
families") as a case of a study, every method on the same trials; this module turns the case
folders into the table a reviewer reads (docs/methods.md, "Judging"):

``families.csv``
    one row per family × method × metric: the RMS over trials ``value`` with its percentile
    bootstrap interval ``[lo, hi]``, and the ratio to ``kf-tuned`` on the same trials with its
    *paired* interval (both RMS values recomputed on the same resamples of trials)::

        ratio = RMS_m / RMS_kf-tuned,   RMS = sqrt(mean over trials of value²)

    The metrics are ``state_settled`` (the whole-state metric), the four settled group metrics
    and ``nees_mean`` (the method's own covariance judged; no interval, no ratio).
``families.md``
    the same as tables, the headroom ``kf-tuned → hindsight`` per family with each method's
    share of it, ``(RMS_kf-tuned − RMS_m) / (RMS_kf-tuned − RMS_hindsight)``, and, for methods
    run over several training seeds (labels ``NAME#SEED``), rliable's IQM over seeds × trials.
``families.png``
    a heat map family × method, colour = ratio to ``kf-tuned`` on ``state_settled`` (blue
    below 1: better; red above), the interval written in each cell.

Everything is read back from the case folders (``trials.csv``, ``summary.csv``), so a resumed
study and ``qkf plot`` give the same table as a fresh run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qkf.core.plotting import Figure, plt
from qkf.core.seed_groups import seed_statistics as core_seed_statistics
from qkf.core.stats import (
    bootstrap_rms,
    min_verdict_trials,
    per_trial_comparison,
    percentile_interval,
    resample_counts,
)
from qkf.core.versus import VersusRow, paired_verdict
from qkf.core.versus import versus_rows as generic_versus_rows
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED
from qkf.transfer_alignment.results import load_bench

REFERENCE = "kf-tuned"
"""The method every ratio is taken against (the best constant κ, tuned with the truth)."""
SHIFT_REFERENCE = "kf-tuned-mixed"
"""The reference of a shift family, where nothing tunes on the family itself: the best
constant κ tuned on the training mixture (:func:`reference_of`)."""


def reference_of(values: dict[str, np.ndarray] | Sequence[str]) -> str:
    """The reference of a family's table: ``kf-tuned`` where it ran, else ``kf-tuned-mixed``
    (a shift family); ``kf-tuned`` when neither ran (the ratios are then empty)."""
    if REFERENCE not in values and SHIFT_REFERENCE in values:
        return SHIFT_REFERENCE
    return REFERENCE


BOUND = "hindsight"
"""The best κ schedule found per trial (a local search with restarts, not a proven optimum:
its certificate is printed beside it): the end of the headroom."""

FAMILY_METRICS: tuple[str, ...] = (
    STATE_SETTLED,
    "att_arcsec_settled",
    "bias_degph_settled",
    "sf_ppm_settled",
    "ma_urad_settled",
    "nees_mean",
)
FAMILIES_COLUMNS: tuple[str, ...] = (
    "family", "method", "metric", "value", "lo", "hi", "reference",
    "ratio_vs_kf_tuned", "ratio_lo", "ratio_hi",
    "median_ratio", "median_lo", "median_hi", "p_improve", "worst_decile", "verdict",
)  # fmt: skip


@dataclass(frozen=True)
class FamilyRow:
    family: str
    method: str
    metric: str
    value: float
    lo: float = math.nan
    hi: float = math.nan
    ratio: float = math.nan
    ratio_lo: float = math.nan
    ratio_hi: float = math.nan
    median: float = math.nan
    median_lo: float = math.nan
    median_hi: float = math.nan
    p_improve: float = math.nan
    worst_decile: float = math.nan
    judged: bool = True
    reference: str = REFERENCE

    @property
    def verdict(self) -> str:
        """Against the reference: ``better`` / ``worse`` when the pooled and the median intervals
        are both below / above 1 (:func:`~..benchmark.paired_verdict`); empty without a
        ratio."""
        if math.isnan(self.ratio):
            return ""
        return paired_verdict(
            self.ratio_lo, self.ratio_hi, self.median_lo, self.median_hi, self.judged
        )

    def cells(self) -> list[object]:
        nums = (
            self.value, self.lo, self.hi, self.ratio, self.ratio_lo, self.ratio_hi,
            self.median, self.median_lo, self.median_hi, self.p_improve, self.worst_decile,
        )  # fmt: skip
        blank = ["" if math.isnan(v) else v for v in nums]
        return [self.family, self.method, self.metric, *blank[:3], self.reference, *blank[3:],
                self.verdict]  # fmt: skip


def family_rows(
    family: str,
    folder: Path,
    values: dict[str, np.ndarray],
    resamples: int,
    level: float,
    seed: int,
) -> list[FamilyRow]:
    """The rows of one family from its case folder (module docstring); ``values``: the
    folder's ``trials.csv`` (:func:`~qkf.transfer_alignment.report.read_trials_csv`, read once
    per case for every table). ``resamples``, ``level``: the paired bootstrap; ``seed`` seeds
    its resamples (reproducible tables)."""
    bench = load_bench(folder)
    cols = [METRIC_COLUMNS.index(m) for m in FAMILY_METRICS if m in METRIC_COLUMNS]
    methods = [m.name for m in bench.methods]
    n = next(iter(values.values())).shape[0]
    counts = resample_counts(n, resamples, seed)
    reps = {m: bootstrap_rms(values[m][:, cols] ** 2, counts) for m in methods}
    point = {m: np.sqrt(np.mean(values[m][:, cols] ** 2, axis=0)) for m in methods}
    judged = n >= min_verdict_trials(level)
    ref = reference_of(values)
    rows = []
    for res in bench.methods:
        m = res.name
        lo, hi = percentile_interval(reps[m], level)
        if ref in values:
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = point[m] / point[ref]
                r_lo, r_hi = percentile_interval(reps[m] / reps[ref], level)
            per = per_trial_comparison(values[m][:, cols], values[ref][:, cols], counts, level)
            trial_part = [per.median, per.median_lo, per.median_hi, per.p_improve,
                          per.worst_decile]  # fmt: skip
        else:
            ratio = r_lo = r_hi = np.full(len(cols), np.nan)
            trial_part = [np.full(len(cols), np.nan)] * 5
        for j, metric in enumerate(FAMILY_METRICS[: len(cols)]):
            pooled_part = (float(ratio[j]), float(r_lo[j]), float(r_hi[j]))
            rows.append(
                FamilyRow(family, m, metric, float(point[m][j]), float(lo[j]), float(hi[j]),
                          *pooled_part, float(trial_part[0][j]), float(trial_part[1][j]),
                          float(trial_part[2][j]), float(trial_part[3][j]),
                          float(trial_part[4][j]), judged, ref)
            )  # fmt: skip
        nees = float(res.summary.get("nees_mean", np.nan))
        rows.append(FamilyRow(family, m, "nees_mean", nees, reference=ref))
    return rows


def versus_rows(
    family: str,
    values: dict[str, np.ndarray],
    focus: Sequence[str],
    resamples: int,
    level: float,
    seed: int,
) -> list[VersusRow]:
    """Each ``focus`` method (a policy, a method of one's own) against every other method of
    the case on ``state_settled`` (``values``: the case's ``trials.csv``), paired over the same
    resamples of trials (:func:`qkf.core.versus.versus_rows`): what a reviewer asks of a
    learned policy (does it beat the clock, the tuned baselines; how far from the hindsight
    bound)."""
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    errors = {m: v[:, j] for m, v in values.items()}
    return generic_versus_rows(family, errors, focus, resamples, level, seed)


def headroom(rows: Sequence[FamilyRow], family: str) -> tuple[float, float] | None:
    """``(RMS_kf-tuned, RMS_hindsight)`` on ``state_settled`` for a family, if both ran."""
    got = {r.method: r.value for r in rows if r.family == family and r.metric == STATE_SETTLED}
    ref = reference_of(list(got))
    if ref in got and BOUND in got:
        return got[ref], got[BOUND]
    return None


def seed_statistics(
    values: dict[str, np.ndarray],
    baselines: Sequence[str],
    level: float,
    reps: int = 2000,
    seed: int = 0,
) -> list[dict[str, object]]:
    """:func:`qkf.core.seed_groups.seed_statistics` of a case's per-trial ``values`` (its
    ``trials.csv``) on ``state_settled``, normalised by :func:`reference_of` (``kf-tuned``, on a
    shift family ``kf-tuned-mixed``): per policy ``NAME#SEED``, the IQM over seeds × trials of
    ``RMS_reference / RMS_m`` with its interval and P(improve) over each baseline."""
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    errors = {m: v[:, j] for m, v in values.items()}
    return core_seed_statistics(errors, baselines, reference_of(values), level, reps, seed)


def families_markdown(
    rows: Sequence[FamilyRow],
    families: Sequence[str],
    trials: int,
    seed: int,
    level: float,
    notes: dict[str, str] | None = None,
    seeds: dict[str, list[dict[str, object]]] | None = None,
    versus: Sequence[VersusRow] = (),
    certificates: dict[str, str] | None = None,
) -> str:
    """``families.md``: per family, a table of every method (state_settled with interval, its
    ratio to kf-tuned with the paired interval, the group ratios, NEES), and the headroom."""
    pct = f"{100 * level:g} %"
    lines = [
        "# Scenario families",
        "",
        f"{trials} trials per family on seed {seed} (every method on the same trials). "
        f"*state* = `state_settled`: the settled RMS over the 15 states of each state's error "
        f"in units of the trial's own final CRLB, over the trial's own settled window. Ratios "
        f"are to `{REFERENCE}` on the same trials: *pooled* = RMS ratio, *median* = median "
        f"per-trial ratio, each with its paired {pct} bootstrap interval; P(impr.) = share of "
        "trials with a ratio below 1; worst 10 % = 90th percentile of the per-trial ratios. "
        "**Bold** (a verdict): the pooled and the median intervals both exclude 1 on the same "
        "side. "
        "Group columns are the pooled ratios of the settled group RMS; NEES = trial-averaged "
        "NEES / 15 over the settled window (1 = consistent). Headroom: "
        f"`{REFERENCE}` → `{BOUND}` (the best κ schedule found per trial with the truth "
        "known, by local searches with restarts: not a proven optimum; the spread of the "
        "searches' optima is printed per family); share = "
        f"(RMS_{REFERENCE} − RMS_m) / (RMS_{REFERENCE} − RMS_{BOUND}).",
    ]
    few = "" if trials >= min_verdict_trials(level) else _too_few(trials, level)
    if few:
        lines += ["", few]
    for fam in families:
        mine = [r for r in rows if r.family == fam]
        if not mine:
            continue
        methods = list(dict.fromkeys(r.method for r in mine))
        get = {(r.method, r.metric): r for r in mine}
        room = headroom(rows, fam)
        ref_name = mine[0].reference
        lines += ["", f"## {fam}", ""]
        if ref_name != REFERENCE:
            lines += [
                f"A shift family: nothing tunes on it, so every tuned baseline is its `-mixed` "
                f"variant (tuned on the training mixture) and the ratios are to `{ref_name}`.",
                "",
            ]
        if room is not None:
            ref, best = room
            lines.append(
                f"Headroom: {ref_name} {ref:.4g} → {BOUND} {best:.4g} "
                f"({100 * (1 - best / ref):.1f} % of {ref_name})."
                if ref > 0
                else ""
            )
            lines.append("")
        cert = (certificates or {}).get(fam)
        if cert:
            lines += [f"`{BOUND}`: {cert}.", ""]
        head = ["method", "state [× CRLB]", f"pooled [{pct}]", f"median [{pct}]", "P(impr.)",
                "worst 10 %", "att", "bias", "sf", "ma", "NEES"]  # fmt: skip
        if room is not None:
            head.append("share")
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for m in methods:
            st = get[(m, STATE_SETTLED)]
            cells = [m, f"{st.value:.4g} [{st.lo:.3g}, {st.hi:.3g}]", *_trial_cells(st)]
            for metric in FAMILY_METRICS[1:5]:
                r = get.get((m, metric))
                cells.append(_ratio_cell(r, interval=False) if r is not None else "–")
            nees = get.get((m, "nees_mean"))
            cells.append(f"{nees.value:.3g}" if nees and np.isfinite(nees.value) else "–")
            if room is not None:
                ref, best = room
                gap = ref - best
                cells.append(f"{(ref - st.value) / gap:.2f}" if gap > 0 else "–")
            lines.append("| " + " | ".join(cells) + " |")
        mine_vs = [v for v in versus if v.family == fam]
        for m in dict.fromkeys(v.method for v in mine_vs):
            mark = {"better": " ↓", "worse": " ↑"}
            cells = [
                f"{v.other} {v.ratio:.3f} [{v.lo:.3f}, {v.hi:.3f}], median {v.median:.3f} "
                f"[{v.median_lo:.3f}, {v.median_hi:.3f}], P(impr.) {v.p_improve:.0%}"
                + mark.get(v.verdict, "")
                for v in mine_vs
                if v.method == m
            ]
            lines += ["", f"`{m}` ÷ each method on `state_settled` (pooled, then median "
                      "per-trial ratio; ↓/↑: both intervals below/above 1): "
                      + "; ".join(cells) + "."]  # fmt: skip
        for stat in (seeds or {}).get(fam, []):
            extra = ", ".join(
                f"P(improve over {k.removeprefix('p_improve_')}) = {v:.2f}"
                for k, v in stat.items()
                if k.startswith("p_improve_") and isinstance(v, float)
            )
            lines += [
                "",
                f"`{stat['policy']}` over {stat['seeds']} training seeds (rliable): IQM of "
                f"RMS_{REFERENCE} / RMS_policy over seeds × trials = {stat['iqm']:.3f} "
                f"[{stat['iqm_lo']:.3f}, {stat['iqm_hi']:.3f}] (above 1: better); {extra}.",
            ]
    if notes:
        lines += ["", "## Methods", ""]
        lines += [f"- `{m}`: {text}" for m, text in notes.items()]
    return "\n".join(lines) + "\n"


def _ratio_cell(r: FamilyRow | None, interval: bool = True) -> str:
    """A group column: the pooled ratio, bold when its interval excludes 1 with enough trials
    (a group ratio alone is not a verdict on the method; the state columns carry that)."""
    if r is None or not np.isfinite(r.ratio):
        return "–"
    text = f"{r.ratio:.3f}" + (f" [{r.ratio_lo:.3f}, {r.ratio_hi:.3f}]" if interval else "")
    decided = r.judged and np.isfinite(r.ratio_lo) and (r.ratio_hi < 1.0 or r.ratio_lo > 1.0)
    return f"**{text}**" if decided else text


def _trial_cells(r: FamilyRow) -> list[str]:
    """The pooled and median ratios with intervals, P(improve) and the worst decile; both
    ratios bold when they make a verdict (:attr:`FamilyRow.verdict`)."""
    if not np.isfinite(r.ratio):
        return ["–"] * 4
    bold = r.verdict in ("better", "worse")
    pooled = f"{r.ratio:.3f} [{r.ratio_lo:.3f}, {r.ratio_hi:.3f}]"
    median = f"{r.median:.3f} [{r.median_lo:.3f}, {r.median_hi:.3f}]"
    if bold:
        pooled, median = f"**{pooled}**", f"**{median}**"
    return [pooled, median, f"{r.p_improve:.0%}", f"{r.worst_decile:.3f}"]


def _too_few(trials: int, level: float) -> str:
    return (
        f"**No verdicts:** {trials} trials per family, fewer than the "
        f"{min_verdict_trials(level)} a verdict needs at {100 * level:g} % (with fewer, the "
        "bootstrap interval of the median per-trial ratio misses the true median more than "
        'twice as often as it should; docs/methods.md, "Per-trial verdicts"). Nothing is bold.'
    )


def families_figure(rows: Sequence[FamilyRow], families: Sequence[str], level: float) -> Figure:
    """The heat map: family × method, colour = ratio to kf-tuned on ``state_settled`` (log
    scale, centred on 1), the ratio and its paired interval in each cell."""
    from matplotlib.colors import LogNorm

    fams = [f for f in families if any(r.family == f for r in rows)]
    methods = list(dict.fromkeys(r.method for r in rows))
    grid = np.full((len(fams), len(methods)), np.nan)
    text = [["" for _ in methods] for _ in fams]
    for r in rows:
        if r.metric != STATE_SETTLED or r.family not in fams:
            continue
        i, j = fams.index(r.family), methods.index(r.method)
        grid[i, j] = r.ratio
        if np.isfinite(r.ratio):
            text[i][j] = f"{r.ratio:.2f}\n[{r.ratio_lo:.2f}, {r.ratio_hi:.2f}]"
    finite = grid[np.isfinite(grid) & (grid > 0)]
    span = float(np.max(np.abs(np.log10(finite)))) if finite.size else 0.1
    span = max(span, 0.05)
    fig, ax = plt.subplots(figsize=(1.1 * len(methods) + 3, 0.7 * len(fams) + 2.2))
    image = ax.imshow(
        np.where(np.isfinite(grid) & (grid > 0), grid, np.nan),
        cmap="RdBu_r", norm=LogNorm(10**-span, 10**span), aspect="auto",
    )  # fmt: skip
    for i in range(len(fams)):
        for j in range(len(methods)):
            ax.text(j, i, text[i][j] or "–", ha="center", va="center", fontsize=7)
    ax.set_xticks(range(len(methods)), methods, rotation=35, ha="right", fontsize=8)
    ax.set_yticks(range(len(fams)), fams, fontsize=8)
    bar = fig.colorbar(image, ax=ax, shrink=0.8)
    bar.set_label(f"state_settled RMS / {REFERENCE} (log)")
    ax.set_title(
        f"Whole-state settled error relative to {REFERENCE} (blue: better), "
        f"paired {100 * level:g} % interval per cell",
        fontsize=10,
    )
    fig.tight_layout()
    return fig
