"""Output files of ``qkf gyros features``, ``run`` and ``bench``: CSV tables, markdown
summaries and PNG plots (formats in docs/redundant_gyros.md, "Output files").

Everything is rendered in memory first and written at the end: a folder through
:func:`qkf.core.io.staged_directory`, a single file atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.io import atomic_write_bytes, atomic_write_text, csv_text, staged_directory
from qkf.core.manifest import manifest, write_manifest
from qkf.core.plotting import figure_png, plt
from qkf.redundant_gyros.benchmark import METHODS, BenchResult
from qkf.redundant_gyros.metrics import (
    DETECTION_METRICS,
    convergence_step,
    convergence_tolerance,
)
from qkf.redundant_gyros.pipeline import RunResult
from qkf.redundant_gyros.threecross import NO_GYRO, FeatureRow
from qkf.redundant_gyros.ukf import DISPLAY_SCALE

FEATURE_COLUMNS = ("gyro", "feature_nominal", "feature_with_errors")
FDI_COLUMNS = (
    "t_s",
    "feature",
    "isolated_threecross",
    "isolated_glt",
    "glt_statistic",
    "model",
    "rate_x_degs",
    "rate_y_degs",
    "rate_z_degs",
)
COEFF_COLUMNS = ("bias_degs", "scale", "delta_u_deg", "delta_v_deg")
CALIBRATION_COLUMNS = ("t_s", "gyro", *COEFF_COLUMNS, *(f"sd_{c}" for c in COEFF_COLUMNS))
COEFF_TITLES = ("bias b (deg/s)", "scale factor λ", "δ_u (deg)", "δ_v (deg)")
BENCH_COLUMNS = (
    "method",
    "kind",
    "size_sigma",
    "trials",
    *(f"{m}{s}" for m in DETECTION_METRICS for s in ("", "_lo", "_hi")),
    "never_detected",
)
UKF_COLUMNS = (
    "t_s",
    *(f"rms_{c}" for c in COEFF_COLUMNS),
    *(f"sd_{c}" for c in COEFF_COLUMNS),
    "nees",
    "band_lo",
    "band_hi",
)


def features_csv_text(rows: list[FeatureRow]) -> str:
    return csv_text(FEATURE_COLUMNS, ([r.gyro, r.nominal, r.with_errors] for r in rows))


def write_features(path: str | Path, rows: list[FeatureRow]) -> None:
    atomic_write_text(path, features_csv_text(rows))


# ----------------------------------------------------------------------------------------------
# run


def _gyro_name(ids: tuple[str, ...], idx: int) -> str:
    return "" if idx == NO_GYRO else ids[idx]


def fdi_csv_text(res: RunResult) -> str:
    ids = res.unit.ids
    names = res.detectors.model_names
    f = res.fdi

    def rows() -> Any:
        for k, t in enumerate(res.data.t):
            yield [
                float(t),
                float(f.feature[0, k]),
                _gyro_name(ids, int(f.isolated_threecross[0, k])),
                _gyro_name(ids, int(f.glt.isolated[0, k])),
                float(f.glt.statistic[0, k]),
                names[int(f.model[0, k])],
                *(float(v) for v in f.rate[0, k]),
            ]

    return csv_text(FDI_COLUMNS, rows())


def calibration_csv_text(res: RunResult) -> str:
    rec = res.record
    if rec is None:
        return csv_text(CALIBRATION_COLUMNS, [])
    gid = res.unit.ids[rec.setup.gyro]
    x = rec.x / DISPLAY_SCALE
    sd = rec.sd / DISPLAY_SCALE
    rows = (
        [float(t), gid, *map(float, x[k]), *map(float, sd[k])]
        for k, t in enumerate(rec.t)
        if np.all(np.isfinite(x[k]))
    )
    return csv_text(CALIBRATION_COLUMNS, rows)


def _feature_figure(res: RunResult) -> bytes:
    unit = res.unit
    t = res.data.t
    fig, ax = plt.subplots(figsize=(10, 5))
    ax.plot(t, res.fdi.feature[0], ".", ms=1.5, color="0.3", label="feature T")
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, gid in enumerate(unit.ids):
        s = unit.signature[i]
        if np.isfinite(s):
            c = colors[i % len(colors)]
            ax.axhspan(s - unit.band, s + unit.band, color=c, alpha=0.25, label=f"{gid} band")
            ax.text(t[-1], s, f" {gid}", va="center", color=c)
    for fault in res.cfg.scenario.faults if res.data.coeffs is not None else []:
        ax.axvline(fault.t_s, color="k", ls="--", lw=0.8)
    finite = res.fdi.feature[0][np.isfinite(res.fdi.feature[0])]
    top = max(float(np.nanmax(unit.signature[np.isfinite(unit.signature)], initial=1.0)) * 2, 3.0)
    if finite.size:
        top = min(max(top, float(np.percentile(finite, 95))), 50.0)
    ax.set_ylim(0.0, top)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("T = |ω1 − ω2| / |ω1 − ω3|")
    ax.set_title(f"three-cross feature and signature bands (±{unit.band:g})")
    ax.legend(loc="upper left", fontsize=7, ncol=3)
    fig.tight_layout()
    return figure_png(fig)


def _glt_figure(res: RunResult) -> bytes:
    fig, ax = plt.subplots(figsize=(10, 4))
    stat = res.fdi.glt.statistic[0]
    ax.semilogy(res.data.t, np.maximum(stat, 1e-3), lw=0.6, label="statistic")
    ax.semilogy(res.data.t, res.fdi.glt.threshold, "r--", lw=1, label="threshold")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("Σ pᵀp over the window")
    ax.set_title(f"parity GLT (window {res.detectors.glt.window} epochs)")
    ax.legend()
    fig.tight_layout()
    return figure_png(fig)


def _calibration_figure(res: RunResult) -> bytes:
    """Estimates against steps since the start (log scale, so the convergence shows), ±3σ,
    and the truth when known."""
    rec = res.record
    assert rec is not None
    x = rec.x / DISPLAY_SCALE
    sd = rec.sd / DISPLAY_SCALE
    truth = res.truth
    step = np.arange(1, rec.t.size + 1)
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for j, ax in enumerate(axes.flat):
        ax.plot(step, x[:, j], lw=1, label="UKF")
        ax.fill_between(
            step, x[:, j] - 3 * sd[:, j], x[:, j] + 3 * sd[:, j], alpha=0.25, label="±3σ"
        )
        shown = x[9:, j]
        if truth is not None:
            ax.plot(step, truth[:, j] / DISPLAY_SCALE[j], "k--", lw=1, label="truth")
            shown = np.concatenate([shown, truth[:, j] / DISPLAY_SCALE[j]])
        shown = shown[np.isfinite(shown)]
        if shown.size:  # the first steps' ±3σ is the wide prior: keep the estimates in view
            lo, hi = float(shown.min()), float(shown.max())
            pad = 0.1 * (hi - lo) or 0.1 * max(abs(hi), 1e-6)
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_xscale("log")
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.set_title(COEFF_TITLES[j])
    for ax in axes[1]:
        ax.set_xlabel(f"UKF steps since t = {rec.t[0]:g} s")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"UKF calibration of gyro {res.unit.ids[rec.setup.gyro]}")
    fig.tight_layout()
    return figure_png(fig)


def _fmt(v: float) -> str:
    return "—" if not np.isfinite(v) else f"{v:.6g}"


def fault_time(res: RunResult) -> float | None:
    """When the simulated run's first fault (or its drawn onset) happens, s; ``None`` for
    recorded readings or a run without a fault (nothing to be early or late against)."""
    if res.data.coeffs is None:
        return None
    times = [f.t_s for f in res.cfg.scenario.faults]
    onset = getattr(res.data, "onset_s", None)
    if onset is not None and np.isfinite(onset[0]) and onset[0] <= res.data.t[-1]:
        times.append(float(onset[0]))
    return min(times) if times else None


def _detector_lines(res: RunResult) -> list[str]:
    """The detectors' table; with a known fault time, also each detector's alarms before the
    fault (false alarms) and its delay after it, and a remark for each that fired early."""
    ids = res.unit.ids
    t = res.data.t
    t_fault = fault_time(res)
    timed = t_fault is not None
    out = [
        "| detector | epochs flagged | first flagged (s) | isolated most often |"
        + (" flagged before the fault | delay after the fault (s) |" if timed else ""),
        "|---|---|---|---|" + ("---|---|" if timed else ""),
    ]
    remarks = []
    for name, iso in (
        ("three-cross", res.fdi.isolated_threecross[0]),
        (f"GLT (window {res.detectors.glt.window})", res.fdi.glt.isolated[0]),
    ):
        hit = iso != NO_GYRO
        first = f"{t[np.argmax(hit)]:.6g}" if hit.any() else "—"
        common = ids[int(np.bincount(iso[hit], minlength=len(ids)).argmax())] if hit.any() else "—"
        row = f"| {name} | {int(hit.sum())} of {iso.size} | {first} | {common} |"
        if t_fault is not None:
            before = hit & (t < t_fault)  # alarms while every gyro was healthy
            after = hit & (t >= t_fault)
            delay = f"{t[np.argmax(after)] - t_fault:.6g}" if after.any() else "missed"
            row += f" {int(before.sum())} | {delay} |"
            if before.any():
                remarks.append(
                    f"- {name} fired {int(before.sum())} epoch"
                    f"{'s' if before.sum() > 1 else ''} before the fault at "
                    f"{t_fault:g} s (first at {t[np.argmax(before)]:.6g} s): false alarms, so "
                    "its first alarm is not the fault's detection."
                )
        out.append(row)
    return out + (["", *remarks] if remarks else [])


def run_summary_md(res: RunResult, source: str) -> str:
    unit = res.unit
    lines = [
        f"# qkf gyros run: {res.cfg.name}",
        "",
        f"Readings: {source}; {res.data.n_epochs} epochs, t = {res.data.t[0]:g} … "
        f"{res.data.t[-1]:g} s.",
        "",
        "## Geometry",
        "",
        "| gyro | three-cross signature | no-fault in-band probability | ‖v_i‖ (parity) |",
        "|---|---|---|---|",
    ]
    norms = np.linalg.norm(unit.v_parity, axis=0)
    p0 = res.detectors.threecross.p0
    for i, gid in enumerate(unit.ids):
        lines.append(f"| {gid} | {_fmt(unit.signature[i])} | {p0[i]:.4f} | {norms[i]:.4f} |")
    findings = unit.separability().lines()
    lines += ["", *(f"- {x}" for x in findings)] if findings else ["", "Every gyro separable."]
    lines += ["", "## Fault detection and isolation", ""]
    if res.data.coeffs is not None and res.cfg.scenario.faults:
        lines += [
            "Faults injected: "
            + "; ".join(
                f"{f.gyro} {f.kind} {f.size} at {f.t_s:g} s" for f in res.cfg.scenario.faults
            ),
            "",
        ]
    lines += _detector_lines(res)
    names = res.detectors.model_names
    used = np.bincount(res.fdi.model[0], minlength=len(names))
    lines += [
        "",
        "Output model (epochs): "
        + ", ".join(f"{names[i]} {int(c)}" for i, c in enumerate(used) if c),
    ]
    lines += ["", "## Calibration (UKF)", ""]
    rec, target = res.record, res.target
    if rec is None or target is None:
        lines.append("No gyro isolated: nothing calibrated.")
        return "\n".join(lines) + "\n"
    tri = "".join(unit.ids[i] for i in rec.setup.triad)
    lines += [
        f"Gyro {unit.ids[target.gyro]} ({target.reason}), from t = {rec.t[0]:g} s, "
        f"{rec.t.size} steps, against the triad {tri}"
        + (" — the filter diverged." if rec.diverged else "."),
        "",
    ]
    last = np.flatnonzero(np.all(np.isfinite(rec.x), axis=1))
    if last.size:
        k = int(last[-1])
        x = rec.x[k] / DISPLAY_SCALE
        sd = rec.sd[k] / DISPLAY_SCALE
        truth = res.truth
        head = "| coefficient | estimate | 1-σ |" + (" truth |" if truth is not None else "")
        lines += [head, "|---|---|---|" + ("---|" if truth is not None else "")]
        for j, name in enumerate(COEFF_TITLES):
            row = f"| {name} | {x[j]:.6g} | {sd[j]:.3g} |"
            if truth is not None:
                row += f" {truth[k, j] / DISPLAY_SCALE[j]:.6g} |"
            lines.append(row)
        if truth is not None:
            step = convergence_step(rec.x[: k + 1] - truth[: k + 1], convergence_tolerance(res.cfg))
            lines += [
                "",
                "Converged (every error within calibration.converged_within to the end): "
                + ("no" if step is None else f"after {step} steps ({rec.t[step] - rec.t[0]:g} s)"),
            ]
    return "\n".join(lines) + "\n"


def write_run(res: RunResult, out_dir: str | Path, source: str, command: list[str] | None) -> None:
    """fdi.csv, calibration.csv, summary.md, feature.png, glt.png, calibration.png, run.json."""
    files: dict[str, bytes] = {
        "fdi.csv": fdi_csv_text(res).encode(),
        "calibration.csv": calibration_csv_text(res).encode(),
        "summary.md": run_summary_md(res, source).encode(),
        "feature.png": _feature_figure(res),
        "glt.png": _glt_figure(res),
    }
    if res.record is not None:
        files["calibration.png"] = _calibration_figure(res)
    info = manifest("gyros-run", res.cfg.model_dump(mode="json"), command, source=source)
    with staged_directory(out_dir) as stage:
        for name, data in files.items():
            atomic_write_bytes(stage / name, data)
        write_manifest(stage, info)


# ----------------------------------------------------------------------------------------------
# bench


def bench_csv_text(res: BenchResult) -> str:
    def rows() -> Any:
        for r in res.rows:
            vals: list[Any] = [r.method, r.kind, r.size_sigma, r.trials]
            for m in DETECTION_METRICS:
                e = r.metrics[m]
                vals += [e.value, e.lo, e.hi]
            yield [*vals, r.never_detected]

    return csv_text(BENCH_COLUMNS, rows())


def ukf_csv_text(res: BenchResult) -> str:
    u = res.ukf
    if u is None:
        return csv_text(UKF_COLUMNS, [])
    rows = (
        [float(t), *map(float, u.rms[k]), *map(float, u.sd[k]), float(u.nees[k]), *u.band]
        for k, t in enumerate(u.t)
    )
    return csv_text(UKF_COLUMNS, rows)


def _bench_figure(res: BenchResult) -> bytes:
    kinds = list(dict.fromkeys(r.kind for r in res.rows))
    fig, axes = plt.subplots(
        2, len(kinds), figsize=(3.2 * len(kinds), 6.5), squeeze=False, sharey="row"
    )
    for col, kind in enumerate(kinds):
        for method in METHODS:
            rows = [r for r in res.rows if r.kind == kind and r.method == method]
            size = np.array([r.size_sigma for r in rows])
            for row, metric in enumerate(("correct_isolation", "missed_detection")):
                est = [r.metrics[metric] for r in rows]
                val = np.array([e.value for e in est])
                err = np.abs(np.array([[e.lo for e in est], [e.hi for e in est]]) - val)
                axes[row, col].errorbar(
                    size, val, yerr=np.nan_to_num(err), marker="o", ms=3, capsize=2, label=method
                )
        axes[0, col].set_title(kind)
        for row in range(2):
            axes[row, col].set_xscale("log", base=2)
            axes[row, col].set_ylim(-0.02, 1.02)
        axes[1, col].set_xlabel("fault size (σ)")
    axes[0, 0].set_ylabel("correct isolation")
    axes[1, 0].set_ylabel("missed detection")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f"detection and isolation over {res.trials} trials per kind and size")
    fig.tight_layout()
    return figure_png(fig)


def _ukf_figure(res: BenchResult) -> bytes:
    u = res.ukf
    assert u is not None
    fig, axes = plt.subplots(1, 5, figsize=(18, 3.8))
    for j in range(4):
        axes[j].semilogy(u.t, u.rms[:, j], label="RMS error")
        axes[j].semilogy(u.t, u.sd[:, j], "--", label="filter 1-σ")
        axes[j].set_title(COEFF_TITLES[j])
        axes[j].set_xlabel("t since start (s)")
    axes[0].legend(fontsize=8)
    axes[4].plot(u.t, u.nees, lw=0.8, label="mean NEES")
    axes[4].axhspan(*u.band, color="g", alpha=0.2, label="χ² band")
    axes[4].set_ylim(0, max(3 * u.band[1], 1.0))
    axes[4].set_title(f"NEES over {u.trials} trials")
    axes[4].legend(fontsize=8)
    fig.suptitle(f"UKF calibration of gyro {u.gyro} (from t = {u.start_s:g} s)")
    fig.tight_layout()
    return figure_png(fig)


def bench_summary_md(res: BenchResult) -> str:
    lines = [
        f"# qkf gyros bench: {res.cfg.name}",
        "",
        f"{res.trials} trials per fault kind and size (fault on gyro k mod n in trial k), "
        f"seed {res.seed}; fault at {res.cfg.bench.fault_time_s:g} s of "
        f"{res.cfg.bench.duration_s:g} s. Intervals: "
        f"{100 * res.cfg.bench.bootstrap.level:g} % percentile bootstrap over trials.",
        "",
        f"FDI cost: {res.fdi_epochs:,} trial-epochs in {res.fdi_seconds:.2f} s "
        f"({1e9 * res.fdi_seconds / max(res.fdi_epochs, 1):.0f} ns per trial-epoch, three "
        "detectors).",
        "",
    ]
    lines += [f"- {x}" for x in res.separability] or ["Every gyro separable."]
    lines += [
        "",
        "| method | kind | size (σ) | false alarm | missed | correct isolation | delay (s) |",
        "|---|---|---|---|---|---|---|",
    ]

    def cell(e: Any) -> str:
        return f"{_fmt(e.value)} [{_fmt(e.lo)}, {_fmt(e.hi)}]"

    for r in res.rows:
        m = r.metrics
        lines.append(
            f"| {r.method} | {r.kind} | {r.size_sigma:g} | {cell(m['false_alarm_rate'])} | "
            f"{cell(m['missed_detection'])} | {cell(m['correct_isolation'])} | "
            f"{cell(m['delay_s'])} |"
        )
    lines += ["", "## UKF calibration", ""]
    u = res.ukf
    if u is None:
        lines.append(res.ukf_note)
    else:
        conv = [s for s in u.converged_step if s is not None]
        inside = float(np.mean((u.nees >= u.band[0]) & (u.nees <= u.band[1])))
        lines += [
            f"Gyro {u.gyro} from t = {u.start_s:g} s (the fault's time: oracle isolation), "
            f"{u.trials} trials, {u.diverged} diverged; {1e6 * u.seconds_per_step:.0f} µs per "
            "step.",
            f"Converged in {len(conv)} of {u.trials} trials"
            + (f", median {int(np.median(conv))} steps." if conv else "."),
            f"Mean NEES inside its χ² band [{u.band[0]:.3g}, {u.band[1]:.3g}] at "
            f"{100 * inside:.1f} % of the steps.",
            "",
            "| coefficient | final RMS error | final filter 1-σ |",
            "|---|---|---|",
        ]
        for j, name in enumerate(COEFF_TITLES):
            lines.append(f"| {name} | {u.rms[-1, j]:.3g} | {u.sd[-1, j]:.3g} |")
    lines += ["", f"Run time {res.runtime_s:.1f} s, {_where(res.backend, res.workers)}."]
    return "\n".join(lines) + "\n"


def _where(backend: str, workers: int) -> str:
    """Where the trials ran, in words (the numbers are the same on every backend)."""
    if backend != "local":
        return f"{backend} backend"
    return "in one process" if workers <= 1 else f"{workers} worker processes"


def write_bench(res: BenchResult, out_dir: str | Path, command: list[str] | None) -> None:
    """bench.csv, ukf.csv, summary.md, bench.png, ukf.png, run.json."""
    files: dict[str, bytes] = {
        "bench.csv": bench_csv_text(res).encode(),
        "ukf.csv": ukf_csv_text(res).encode(),
        "summary.md": bench_summary_md(res).encode(),
        "bench.png": _bench_figure(res),
    }
    if res.ukf is not None:
        files["ukf.png"] = _ukf_figure(res)
    info = manifest(
        "gyros-bench",
        res.cfg.model_dump(mode="json"),
        command,
        trials=res.trials,
        seed=res.seed,
        backend=res.backend,
        workers=res.workers,
    )
    with staged_directory(out_dir) as stage:
        for name, data in files.items():
            atomic_write_bytes(stage / name, data)
        write_manifest(stage, info)
