"""The tables of ``qkf bench`` and ``qkf crlb``: the rows of every CSV file and the markdown
summary, in display units (formats in docs/architecture.md, "Output files"). The figures are
:mod:`.bench_figures`; writing the folder and reading it back is :mod:`.results`."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from qkf.core.io import csv_text
from qkf.core.stats import average_nees_band, min_verdict_trials
from qkf.transfer_alignment.benchmark import NEES_COLUMNS, BenchResult, MethodResult
from qkf.transfer_alignment.crlb import CrlbResult
from qkf.transfer_alignment.divergence import divergence_lines
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, WINDOWS, recovery_times, summarize
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

TRIAL_COLUMNS: tuple[str, ...] = ("method", "trial", *METRIC_COLUMNS)
PAIRED_COLUMNS: tuple[str, ...] = (
    "method", "baseline", "metric", "ratio", "lo", "hi",
    "median_ratio", "median_lo", "median_hi", "p_improve", "worst_decile", "verdict",
)  # fmt: skip
"""paired.csv: the pooled RMS ratio and its paired interval (docs/architecture.md), then the
per-trial comparison (median ratio and interval, P(improve), worst decile) and the verdict
(docs/methods.md, "Per-trial verdicts")."""
UNITS = {"att_arcsec": "arcsec", "bias_degph": "deg/h", "sf_ppm": "ppm", "ma_urad": "µrad"}


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


def crlb_csv_text(result: CrlbResult) -> str:
    """``t_s`` plus the 15 one-sigma bounds in display units (docs/architecture.md)."""
    disp = result.bound / DISPLAY_UNIT
    return csv_text(
        ("t_s", *STATE_COLUMNS),
        ([float(t), *map(float, row)] for t, row in zip(result.t, disp, strict=True)),
    )


__all__ = [
    "METRIC_COLUMNS",
    "PAIRED_COLUMNS",
    "SUMMARY_COLUMNS",
    "TRIAL_COLUMNS",
    "bench_tables",
    "summary_markdown",
]
