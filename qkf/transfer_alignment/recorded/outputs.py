"""The files of a recorded run (docs/recorded_data.md, "Output"): ``estimates.csv``,
``quality.csv``, ``final.csv``, ``summary.md``, ``estimates.png``, ``nis.png``, ``run.json``;
with truth, every file of a benchmark as well (:mod:`qkf.transfer_alignment.report`).

``estimates.csv`` can be large (a day at 10 Hz is 864,000 rows per method), so it is streamed
to disk in blocks of rows (pyarrow's CSV writer) rather than rendered in memory.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from qkf.core.io import atomic_write_bytes, csv_text, staged_directory
from qkf.core.manifest import manifest, write_manifest
from qkf.core.plotting import figure_png
from qkf.transfer_alignment.bench_figures import bench_figures
from qkf.transfer_alignment.divergence import divergence_lines
from qkf.transfer_alignment.recorded.quality import (
    LAGS,
    QUALITY_COLUMNS,
    nis_band,
)
from qkf.transfer_alignment.recorded.run import RecordedResult
from qkf.transfer_alignment.report import RMS_COLUMNS, bench_tables
from qkf.transfer_alignment.results import bench_manifest
from qkf.transfer_alignment.states import DISPLAY_UNIT, STATE_COLUMNS

CALIBRATION_COLUMNS = STATE_COLUMNS[3:]
"""The twelve calibration states (bias, scale factor, misalignment), display units."""
ATTITUDE_SD_COLUMNS = tuple(f"{c}_sd" for c in STATE_COLUMNS[:3])
ESTIMATE_COLUMNS: tuple[str, ...] = (
    "t_s",
    "method",
    "trial",
    "qx",
    "qy",
    "qz",
    "qw",
    *(name for c in CALIBRATION_COLUMNS for name in (c, f"{c}_sd")),
    *ATTITUDE_SD_COLUMNS,
    "kappa",
)
"""estimates.csv: per recorded row and method, the estimate and its 1σ (display units)."""
FINAL_COLUMNS = ("method", "trial", "state", "estimate", "sd", "lo", "hi")
"""final.csv: the calibration after the last epoch, with its 95 % interval (±1.96 σ)."""
Z95 = 1.959963984540054
BLOCK_ROWS = 131_072
"""Rows per block written to estimates.csv."""


def _estimate_block(res: RecordedResult, run_index: int, trial: int, rows: np.ndarray) -> pa.Table:
    """estimates.csv rows of one method and trial at grid epochs ``rows``."""
    run = res.methods[run_index]
    info = res.recorded.files[trial]
    out = run.out
    est = out.est[trial, rows]
    cols: dict[str, Any] = {
        "t_s": info.t_s[np.searchsorted(info.epoch, rows)],
        "method": pa.array([run.name] * rows.size, pa.string()),
        "trial": np.full(rows.size, trial, dtype=np.int64),
    }
    for j, c in enumerate(("qx", "qy", "qz", "qw")):
        cols[c] = est[:, j]
    calib = est[:, 4:16] / DISPLAY_UNIT[3:]
    sd = None if out.var is None else np.sqrt(out.var[trial, rows]) / DISPLAY_UNIT
    for j, c in enumerate(CALIBRATION_COLUMNS):
        cols[c] = calib[:, j]
        cols[f"{c}_sd"] = pa.nulls(rows.size, pa.float64()) if sd is None else sd[:, 3 + j]
    for j, c in enumerate(ATTITUDE_SD_COLUMNS):
        cols[c] = pa.nulls(rows.size, pa.float64()) if sd is None else sd[:, j]
    cols["kappa"] = (
        pa.nulls(rows.size, pa.float64()) if out.kappa is None else out.kappa[trial, rows]
    )
    return pa.table(cols)


def write_estimates(res: RecordedResult, path: Path) -> None:
    """Stream estimates.csv to ``path`` (a staging folder's file: written once)."""

    def blocks() -> Iterator[pa.Table]:
        for i in range(len(res.methods)):
            for trial, info in enumerate(res.recorded.files):
                for start in range(0, info.epoch.size, BLOCK_ROWS):
                    yield _estimate_block(res, i, trial, info.epoch[start : start + BLOCK_ROWS])

    # a plain header, as every other CSV of a run (pyarrow would quote the names)
    stream_csv(path, ESTIMATE_COLUMNS, blocks())


def stream_csv(path: Path, header: tuple[str, ...], blocks: Iterator[pa.Table]) -> None:
    """Write ``header`` and the tables of ``blocks`` (its columns, in order) to ``path``."""
    with pa.OSFile(str(path), "wb") as sink:
        sink.write((",".join(header) + "\n").encode())
        writer: pacsv.CSVWriter | None = None
        schema = None
        for table in blocks:
            if writer is None:
                schema = table.schema
                opts = pacsv.WriteOptions(include_header=False)
                writer = pacsv.CSVWriter(sink, schema, write_options=opts)
            writer.write_table(table.cast(schema))
        if writer is not None:
            writer.close()


def _per_epoch_blocks(
    names: list[str], t: np.ndarray, values: list[np.ndarray]
) -> Iterator[pa.Table]:
    """rms.csv / crlb.csv rows: per name (None: no method column), ``t`` and its (N, 15)."""
    for name, v in zip(names, values, strict=True):
        for start in range(0, t.size, BLOCK_ROWS):
            sl = slice(start, start + BLOCK_ROWS)
            cols: dict[str, Any] = {}
            if name:
                cols["method"] = pa.array([name] * t[sl].size, pa.string())
            cols["t_s"] = t[sl]
            for j, c in enumerate(STATE_COLUMNS):
                cols[c] = np.ascontiguousarray(v[sl, j])
            yield pa.table(cols)


def quality_rows(res: RecordedResult) -> list[list[object]]:
    return [q.row(m.name, t) for m in res.methods for t, qs in enumerate(m.quality) for q in qs]


def final_rows(res: RecordedResult) -> list[list[object]]:
    """The last epoch's calibration of every method and trial, display units, ±1.96 σ."""
    rows: list[list[object]] = []
    for m in res.methods:
        for trial in range(res.recorded.data.n_trials):
            est = m.out.est[trial, -1, 4:16] / DISPLAY_UNIT[3:]
            sd = (
                np.full(12, np.nan)
                if m.out.var is None
                else np.sqrt(m.out.var[trial, -1, 3:]) / DISPLAY_UNIT[3:]
            )
            for j, c in enumerate(CALIBRATION_COLUMNS):
                e, s = float(est[j]), float(sd[j])
                rows.append([m.name, trial, c, e, s, e - Z95 * s, e + Z95 * s])
    return rows


def _fmt(v: float, digits: int = 3) -> str:
    return "–" if not np.isfinite(v) else f"{v:.{digits}g}"


def summary_markdown(res: RecordedResult) -> str:
    """The recorded-data part of summary.md: files, truth-free consistency, final calibration."""
    rec, cfg = res.recorded, res.cfg
    lines = [
        f"# Recorded data: {len(rec.files)} file(s), step {cfg.scenario.dt_s:.6g} s, "
        f"{rec.data.n_epochs:,} epochs",
        "",
        "| trial | file | rows | rows used | held epochs | rows without every measurement "
        "| updates | SHA-256 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for i, f in enumerate(rec.files):
        lines.append(
            f"| {i} | {f.path.name} | {f.rows:,} | {f.epoch.size:,} | {f.held_epochs:,} | "
            f"{f.partial_rows:,} | {f.updates:,} | `{f.sha256[:16]}…` |"
        )
    if res.bench is None:  # with truth, the benchmark's part of summary.md names them
        lines = [*lines[:2], *divergence_lines(res.divergences, res.file_names), *lines[2:]]
    if any(f.partial_rows for f in rec.files):
        lines += [
            "",
            "Rows with an ADS attitude but no ADS rate (or the reverse) are filtered without an "
            "update: the filter updates on every measurement it is configured for "
            f"(`filter.matching: {cfg.filter.matching}`) or on none.",
        ]
    if any(f.held_epochs for f in rec.files):
        lines += [
            "",
            "Held epochs: dropped samples, filled with the gyro reading held and no update "
            "(docs/recorded_data.md).",
        ]
    lo, hi = nis_band(3)
    lines += [
        "",
        f"## Consistency without truth (t ≥ {cfg.run.settled_s:g} s)",
        "",
        f"Per epoch the NIS of a 3-row block lies in [{lo:.3g}, {hi:.3g}] with probability 95 % "
        f"when the filter's noise model fits the data; its mean /3 is 1. Whiteness: "
        f"autocorrelation of the innovations at lags 1–{LAGS} (white: 5 % outside their band).",
        "",
        "| method | trial | block | epochs | mean NIS/3 | 99.9 % band | inside 95 % band "
        "| max \\|ρ\\| | ρ outside band |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    flags: list[str] = []
    silent = []
    unjudged: list[str] = []
    judged = 0
    for m in res.methods:
        if not any(m.quality):
            silent.append(m.name)
        for t, qs in enumerate(m.quality):
            for q in qs:
                judged += q.epochs
                if q.epochs == 0:
                    unjudged.append(f"{m.name} (trial {t}, {q.block})")
                lines.append(
                    f"| {m.name} | {t} | {q.block} | {q.epochs:,} | {_fmt(q.nis_mean)} | "
                    f"[{_fmt(q.nis_mean_lo)}, {_fmt(q.nis_mean_hi)}] | {_pct(q.in_band)} "
                    f"| {_fmt(q.whiteness_max, 2)} | {_pct(q.whiteness_outside)} |"
                )
                flags += [f"- **{m.name}**, trial {t}: {f}" for f in q.flags]
    lines.append("")
    if silent:
        lines += [
            f"Not judged (the method reports no per-epoch NIS): {', '.join(silent)}.",
            "",
        ]
    if unjudged:
        lines += [
            "Not judged (no update with a finite NIS in the window: a diverged filter, or no "
            f"measurement there): {', '.join(unjudged)}.",
            "",
        ]
    if flags:
        lines += ["**Flagged** — the data refute the filter's noise model:", "", *flags]
    elif judged:
        lines.append(
            f"No flag on the {judged:,} judged epoch-blocks: every judged filter's innovations "
            "fit its noise model there."
        )
    else:
        lines.append("Nothing judged: no method has a finite NIS in the window.")
    lines += [
        "",
        "## Final calibration (last epoch, ± 1.96 σ)",
        "",
        "| method | trial | " + " | ".join(CALIBRATION_COLUMNS) + " |",
        "|---|---|" + "---|" * len(CALIBRATION_COLUMNS),
    ]
    rows = final_rows(res)
    for i in range(0, len(rows), 12):
        block = rows[i : i + 12]
        cells = [
            f"{_fmt(float(r[3]), 4)} ± {_fmt(Z95 * float(r[4]), 2)}"  # type: ignore[arg-type]
            for r in block
        ]
        lines.append(f"| {block[0][0]} | {block[0][1]} | " + " | ".join(cells) + " |")
    runtime = ", ".join(f"{m.name} {m.runtime_s:.2f} s" for m in res.methods)
    lines += ["", f"Run time: {runtime}.", ""]
    return "\n".join(lines)


def _pct(v: float) -> str:
    return "–" if not np.isfinite(v) else f"{100 * v:.1f} %"


def _decimate(n: int, points: int = 2000) -> np.ndarray:
    return np.unique(np.append(np.arange(0, n, max(1, n // points)), n - 1))


def estimates_png(res: RecordedResult, trial: int = 0) -> bytes:
    """Each calibration state of ``trial`` over time: every method's estimate ±1σ (and the
    truth when the file has it)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    info = res.recorded.files[trial]
    pick = info.epoch[_decimate(info.epoch.size)]
    t = info.t_s[np.searchsorted(info.epoch, pick)] - info.t0_s
    fig, axes = plt.subplots(4, 3, figsize=(13, 11), sharex=True)
    truth = None
    if res.recorded.has_truth:
        d = res.recorded.data
        truth = np.concatenate([d.bias[trial, pick], d.calib[trial, pick]], axis=1)
        truth = truth / DISPLAY_UNIT[3:]
    # the y range of the settled window: the first epochs' prior band would flatten the rest
    settled = res.recorded.data.t[pick] >= res.cfg.run.settled_s
    if not settled.any():
        settled[:] = True
    for j, (ax, col) in enumerate(zip(axes.flat, CALIBRATION_COLUMNS, strict=True)):
        span: list[np.ndarray] = []
        for i, m in enumerate(res.methods):
            est = m.out.est[trial, pick, 4 + j] / DISPLAY_UNIT[3 + j]
            (line,) = ax.plot(t, est, lw=1.0, label=m.name, color=f"C{i % 10}")
            span.append(est[settled])
            if m.out.var is not None:
                sd = np.sqrt(m.out.var[trial, pick, 3 + j]) / DISPLAY_UNIT[3 + j]
                ax.fill_between(t, est - sd, est + sd, color=line.get_color(), alpha=0.2, lw=0)
                span += [(est - sd)[settled], (est + sd)[settled]]
        if truth is not None:
            ax.plot(t, truth[:, j], "k--", lw=0.8, label="truth")
            span.append(truth[settled, j])
        vals = np.concatenate(span)
        vals = vals[np.isfinite(vals)]
        if vals.size:
            lo, hi = float(vals.min()), float(vals.max())
            pad = 0.15 * max(hi - lo, 1e-3 * max(abs(lo), abs(hi)), 1e-9)
            ax.set_ylim(lo - pad, hi + pad)
        ax.set_title(col, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel(f"t − {info.t0_s:.6g} s")
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(6, len(labels)), fontsize=8)
    fig.suptitle(f"{info.path.name}: estimates ±1σ (display units)", fontsize=10)
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    png = figure_png(fig)
    plt.close(fig)
    return png


def nis_png(res: RecordedResult, trial: int = 0) -> bytes | None:
    """Moving mean of each block's NIS/3 of ``trial`` with the 95 % band of such a mean."""
    judged = [m for m in res.methods if m.out.nis is not None]
    if not judged:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import stats

    blocks = ["attitude"] + (["rate"] if res.cfg.filter.matching == "attitude_rate" else [])
    info = res.recorded.files[trial]
    n = res.recorded.data.n_epochs
    fig, axes = plt.subplots(len(blocks), 1, figsize=(10, 3.2 * len(blocks)), squeeze=False)
    width = max(1, n // 300)  # epochs per mean
    t = res.recorded.data.t + info.t0_s
    for ax, (c, name) in zip(axes[:, 0], enumerate(blocks), strict=True):
        w_eff = 1
        for i, m in enumerate(judged):
            assert m.out.nis is not None
            v = m.out.nis[trial, :, c] / 3.0
            ok = np.isfinite(v)
            cnt = np.convolve(ok, np.ones(width), "valid")
            tot = np.convolve(np.where(ok, v, 0.0), np.ones(width), "valid")
            with np.errstate(invalid="ignore", divide="ignore"):
                mean = tot / cnt
            w_eff = max(1, int(np.median(cnt[cnt > 0]))) if (cnt > 0).any() else 1
            step = max(1, mean.size // 1500)
            ax.plot(t[width - 1 :: step][: mean[::step].size], mean[::step], lw=0.9,
                    label=m.name, color=f"C{i % 10}")  # fmt: skip
        lo, hi = stats.chi2.ppf([0.025, 0.975], 3 * w_eff) / (3 * w_eff)
        ax.axhspan(lo, hi, color="0.85", zorder=0, label=f"95 % band of a mean of {w_eff}")
        ax.axhline(1.0, color="k", lw=0.6)
        top = max((ln.get_ydata().max() for ln in ax.get_lines()[:-1] if ln.get_ydata().size),
                  default=1.0)  # fmt: skip
        if np.isfinite(top) and top > 3.0:  # a misfit of several times: a log axis reads it
            ax.set_yscale("log")
        ax.set_ylabel(f"{name} NIS / 3")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=8, ncol=4)
    fig.suptitle(f"{info.path.name}: NIS (moving mean over {width} epochs)", fontsize=10)
    fig.tight_layout()
    png = figure_png(fig)
    plt.close(fig)
    return png


def recorded_manifest(res: RecordedResult, command: list[str] | None) -> dict[str, Any]:
    """run.json of a recorded run: the usual benchmark manifest with truth, a ``bench-recorded``
    one without; both name every data file with its SHA-256."""
    data = {"data": res.recorded.manifest(), "has_truth": res.recorded.has_truth}
    if res.bench is not None:
        return {**bench_manifest(res.bench, command), **data}
    return manifest(
        RECORDED_KIND,
        res.cfg.model_dump(mode="json"),
        command,
        methods=[{"name": m.name, "spec": m.spec} for m in res.methods],
        trials=res.recorded.data.n_trials,
        **data,
    )


RECORDED_KIND = "bench-recorded"
"""run.json kind of a recorded run without truth (with truth it is a ``bench`` run)."""


def write_recorded_run(
    res: RecordedResult, out_dir: str | Path, command: list[str] | None = None
) -> list[Path]:
    """Write every file of ``res`` into ``out_dir`` (staged: replaced whole, or left as it was
    if anything fails)."""
    files: dict[str, bytes] = {}
    if res.bench is not None:
        # rms.csv and crlb.csv have a row per epoch: streamed below (a day at 10 Hz would take
        # gigabytes rendered in memory)
        files.update(bench_tables(res.bench, per_epoch=False, trial_names=res.file_names))
        files.update(bench_figures(res.bench))
    recorded_md = summary_markdown(res)
    files["summary.md"] = (
        files["summary.md"].decode() + "\n" + recorded_md if "summary.md" in files else recorded_md
    ).encode()
    files["quality.csv"] = csv_text(QUALITY_COLUMNS, quality_rows(res)).encode()
    files["final.csv"] = csv_text(FINAL_COLUMNS, final_rows(res)).encode()
    files["estimates.png"] = estimates_png(res)
    nis = nis_png(res)
    if nis is not None:
        files["nis.png"] = nis
    out = Path(out_dir)
    with staged_directory(out) as stage:
        for name, content in files.items():
            atomic_write_bytes(stage / name, content)
        write_estimates(res, stage / "estimates.csv")
        streamed = ["estimates.csv"]
        if res.bench is not None:
            b = res.bench
            stream_csv(
                stage / "rms.csv",
                RMS_COLUMNS,
                _per_epoch_blocks([m.name for m in b.methods], b.t,
                                  [m.rms / DISPLAY_UNIT for m in b.methods]),
            )  # fmt: skip
            stream_csv(
                stage / "crlb.csv",
                RMS_COLUMNS[1:],
                _per_epoch_blocks([""], b.bound.t, [b.bound.bound / DISPLAY_UNIT]),
            )
            streamed += ["rms.csv", "crlb.csv"]
        write_manifest(stage, recorded_manifest(res, command))
    return [out / name for name in (*files, *streamed, "run.json")]
