"""Output files and plots of ``qkf fuse`` (docs/sca_fusion.md, "Outputs").

Everything is computed first and then written into a staged folder that replaces ``--out`` whole
(:func:`qkf.core.io.staged_directory`), so a failed run leaves nothing behind.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qkf.core.io import atomic_write_bytes, atomic_write_text, csv_text, staged_directory
from qkf.core.manifest import manifest, write_manifest
from qkf.sca_fusion.config import FusionConfig
from qkf.sca_fusion.design import AXES
from qkf.sca_fusion.differentiation import quat_conj, quat_log, quat_mul
from qkf.sca_fusion.fusion import FusionRun
from qkf.sca_fusion.scenario import ARCSEC

FUSED_COLUMNS = ("t_s", "q_x", "q_y", "q_z", "q_w", "sigma_x_rad", "sigma_y_rad", "sigma_z_rad")
VC_COLUMNS = ("arc", "group", "axis", "sigma")
SOLUTION_COLUMNS = ("arc", "parameter", "value", "sd")
EPOCH_SIGMA_COLUMNS = ("t_s", "sca", "acc")
ACC_COLUMNS = ("t_s", "dw_x", "dw_y", "dw_z")
PLOTS = ("residuals.png", "epoch_sigma.png", "spectra.png")


@dataclass(frozen=True)
class TruthComparison:
    """Errors against the simulated truth at the star-camera epochs (rad, per axis)."""

    rms_fused: np.ndarray
    rms_sca: np.ndarray
    predicted_fused: np.ndarray  # sqrt(mean σ_fused²) (rad, from the estimator's covariance)
    predicted_ratio: np.ndarray  # predicted_fused / σ̂_sca (from the estimator itself)
    fused_error: list[np.ndarray]  # per arc (n, 3), NaN-free
    sca_error: list[np.ndarray]  # per arc (n, 3), NaN where no star camera
    outliers: int
    outlier_min_factor: float


def _truth_at(run: FusionRun, t: np.ndarray) -> np.ndarray:
    assert run.simulation is not None
    idx = np.searchsorted(run.simulation.t, t - 1e-9)
    return run.simulation.q_true[idx]


def compare_with_truth(run: FusionRun) -> TruthComparison | None:
    """RMS errors of the fused and of the star-camera-only attitude against the truth."""
    if run.simulation is None or not run.solutions:
        return None
    fused, sca, sig2, sca_sig2 = [], [], [], []
    for arc, sol in zip(run.arcs, run.solutions, strict=True):
        truth = _truth_at(run, sol.t)
        fused.append(quat_log(quat_mul(quat_conj(truth), sol.q)))
        e = np.full((sol.t.size, 3), np.nan)
        m = arc.has_sca
        e[m] = quat_log(quat_mul(quat_conj(truth[m]), arc.sca_q[m]))
        sca.append(e)
        sig2.append(sol.sigma[m] ** 2)
        sca_sig2.append(np.broadcast_to(sol.sigma_sca**2, (int(m.sum()), 3)))
    f_at_sca = np.concatenate([f[a.has_sca] for f, a in zip(fused, run.arcs, strict=True)])
    s_at_sca = np.concatenate([s[a.has_sca] for s, a in zip(sca, run.arcs, strict=True)])
    predicted_fused = np.sqrt(np.concatenate(sig2).mean(0))
    predicted = predicted_fused / np.sqrt(np.concatenate(sca_sig2).mean(0))
    sim = run.simulation
    factors = []
    for sol in run.solutions:
        hit = np.isin(np.round(sol.t, 6), np.round(sim.outlier_t, 6))
        factors.append(sol.epoch_sigma_sca[hit])
    f_all = np.concatenate(factors) if factors else np.zeros(0)
    return TruthComparison(
        rms_fused=np.sqrt(np.mean(f_at_sca**2, axis=0)),
        rms_sca=np.sqrt(np.mean(s_at_sca**2, axis=0)),
        predicted_fused=predicted_fused,
        predicted_ratio=predicted,
        fused_error=fused,
        sca_error=sca,
        outliers=int(f_all.size),
        outlier_min_factor=float(np.nanmin(f_all)) if f_all.size else float("nan"),
    )


def _opt(v: float) -> float | str:
    return "" if not np.isfinite(v) else float(v)


def fused_rows(run: FusionRun) -> list[list[float]]:
    rows = []
    for sol in run.solutions:
        block = np.column_stack([sol.t, sol.q, sol.sigma])
        rows.extend(block.tolist())
    return rows


def variance_rows(run: FusionRun) -> list[list[object]]:
    rows: list[list[object]] = []
    for k, sol in enumerate(run.solutions):
        for group, sig, comps in (
            ("sca", sol.sigma_sca, sol.sca_components),
            ("acc", sol.sigma_acc, sol.acc_components),
        ):
            if group == "acc" and not sol.has_acc.any():
                continue
            for j, name in enumerate(comps):
                rows.append([k, group, name, float(sig[j])])
    return rows


def solution_rows(run: FusionRun) -> list[list[object]]:
    rows: list[list[object]] = []
    for k, sol in enumerate(run.solutions):
        for name, v, sd in zip(sol.layout.names, sol.calibration, sol.calibration_sd, strict=True):
            rows.append([k, name, float(v), float(sd)])
    return rows


def epoch_sigma_rows(run: FusionRun) -> list[list[object]]:
    rows: list[list[object]] = []
    for sol in run.solutions:
        for t, s, a in zip(sol.t, sol.epoch_sigma_sca, sol.epoch_sigma_acc, strict=True):
            rows.append([float(t), _opt(s), _opt(a)])
    return rows


def acc_rows(run: FusionRun) -> list[list[float]]:
    rows = []
    for sol in run.solutions:
        m = sol.has_acc
        rows.extend(np.column_stack([sol.t[m], sol.acc_calibrated[m]]).tolist())
    return rows


def _fmt(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}"


def summary_text(cfg: FusionConfig, run: FusionRun, truth: TruthComparison | None) -> str:
    """The run in a few tables (markdown)."""
    est = cfg.estimator
    lines = [
        f"# qkf fuse: {cfg.name}",
        "",
        f"Source: {run.source}.",
        "",
        f"Estimator: interpolation degree {est.interpolation_degree}, at most "
        f"{est.iteration_count} iterations (stop when σ₀ changes by < "
        f"{est.convergence_sigma0:g}), variance components "
        f"{'on' if est.variance_component_estimation else 'off'} (star camera "
        f"{'per axis' if est.estimate_sigma_sca_per_axis else 'one factor'}, accelerometer "
        f"{'per axis' if est.estimate_sigma_acc_per_axis else 'one factor'}), Huber "
        + (f"{est.huber:g}, power {est.huber_power:g}" if est.huber is not None else "off")
        + f", Euler correction {'on' if est.euler_correction.enabled else 'off'}.",
        "",
        "## Arcs",
        "",
        "| arc | start (s) | end (s) | epochs | without star camera | without accelerometer "
        "| iterations | converged | σ₀ |",
        "|---:|---:|---:|---:|---:|---:|---:|:---:|---:|",
    ]
    for k, sol in enumerate(run.solutions):
        lines.append(
            f"| {k} | {sol.t[0]:.6g} | {sol.t[-1]:.6g} | {sol.t.size} | "
            f"{int((~sol.has_sca).sum())} | {int((~sol.has_acc).sum())} | {sol.iterations} | "
            f"{'yes' if sol.converged else 'no'} | {_fmt(sol.sigma0[-1])} |"
        )
    if not run.solutions:
        lines.append("| – | | | | | | | | |")
    if run.skipped:
        lines += ["", "Skipped: " + "; ".join(run.skipped) + "."]
    lines += [
        "",
        "## Variance components",
        "",
        "| arc | group | axis | sigma | display |",
        "|---:|---|---|---:|---:|",
    ]
    for arc, group, axis, sig in variance_rows(run):
        assert isinstance(sig, float)
        disp = f"{sig / ARCSEC:.4g} arcsec" if group == "sca" else f"{sig:.4g} rad/s²"
        lines.append(f"| {arc} | {group} | {axis} | {sig:.6g} | {disp} |")
    lines += [
        "",
        "## Accelerometer calibration",
        "",
        "| arc | parameter | value | sd | truth | (est − truth)/sd |",
        "|---:|---|---:|---:|---:|---:|",
    ]
    sim = run.simulation
    for arc, name, v, sd in solution_rows(run):
        assert isinstance(name, str) and isinstance(v, float) and isinstance(sd, float)
        truth_v, z = "", ""
        if sim is not None:
            axis = AXES.index(name.split("_")[2])
            ref = sim.acc_bias_rad_s2 if name.startswith("acc_bias") else sim.acc_scale
            truth_v = f"{ref[axis]:.4g}"
            z = f"{(v - ref[axis]) / sd:+.2f}"
        lines.append(f"| {arc} | {name} | {v:.6g} | {sd:.3g} | {truth_v} | {z} |")
    lines += ["", "## Robust weights", ""]
    for k, sol in enumerate(run.solutions):
        s_out = int(np.sum(sol.epoch_sigma_sca > 1.0))
        a_out = int(np.sum(sol.epoch_sigma_acc > 1.0))
        smax = np.nanmax(np.r_[sol.epoch_sigma_sca, 1.0])
        amax = np.nanmax(np.r_[sol.epoch_sigma_acc, 1.0])
        lines.append(
            f"- arc {k}: {s_out} star-camera epochs downweighted (largest factor "
            f"{smax:.3g}), {a_out} accelerometer epochs (largest {amax:.3g})."
        )
    if truth is not None:
        lines += [
            "",
            "## Against the simulated truth (star-camera epochs)",
            "",
            "| axis | star camera alone | fused | fused, predicted | ratio | predicted ratio |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for j, a in enumerate(AXES):
            lines.append(
                f"| {a} | {truth.rms_sca[j] / ARCSEC:.4g} | {truth.rms_fused[j] / ARCSEC:.4g} | "
                f"{truth.predicted_fused[j] / ARCSEC:.4g} | "
                f"{truth.rms_fused[j] / truth.rms_sca[j]:.3f} | {truth.predicted_ratio[j]:.3f} |"
            )
        lines += [
            "",
            "RMS errors in arcsec. Fused, predicted: sqrt(mean σ_fused²) from the estimator's own "
            "covariance; predicted ratio: that over the estimated star-camera sigma (the star "
            "camera alone includes its outliers, if any).",
        ]
        if truth.outliers:
            lines.append(
                f"Injected star-camera outliers: {truth.outliers}; smallest epoch sigma factor "
                f"among them {truth.outlier_min_factor:.3g}."
            )
    return "\n".join(lines) + "\n"


def amplitude_spectral_density(
    x: np.ndarray, fs: float, nperseg: int
) -> tuple[np.ndarray, np.ndarray]:
    """Welch estimate, as ``scipy.signal.welch`` with its defaults (without importing it, which
    takes seconds): periodic-Hann segments overlapping by half, mean removed per segment.
    Returns frequencies (Hz) and the one-sided amplitude spectral density (unit/√Hz)."""
    nper = min(nperseg, x.size)
    step = max(nper - nper // 2, 1)  # overlap nper // 2
    starts = range(0, x.size - nper + 1, step)
    win = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nper) / nper)  # periodic Hann
    segs = np.stack([x[s : s + nper] for s in starts])
    segs = (segs - segs.mean(axis=1, keepdims=True)) * win
    psd = np.mean(np.abs(np.fft.rfft(segs, axis=1)) ** 2, axis=0) / (fs * np.sum(win**2))
    psd[1 : (nper + 1) // 2] *= 2.0  # one-sided: fold the negative frequencies
    return np.fft.rfftfreq(nper, 1.0 / fs), np.sqrt(psd)


def longest_star_camera_run(run: FusionRun) -> tuple[int, int, int] | None:
    """``(arc, start, stop)`` of the longest stretch of consecutive star-camera epochs (the
    spectra need an uninterrupted series)."""
    best: tuple[int, int, int] | None = None
    for k, arc in enumerate(run.arcs):
        m = np.concatenate([[False], arc.has_sca, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(m))
        for lo, hi in zip(edges[::2], edges[1::2], strict=True):
            if best is None or hi - lo > best[2] - best[1]:
                best = (k, int(lo), int(hi))
    return best


def _plots(run: FusionRun, truth: TruthComparison | None) -> dict[str, bytes]:
    from qkf.core.plotting import figure_png, plt

    out: dict[str, bytes] = {}
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for k, sol in enumerate(run.solutions):
        for j, ax in enumerate(axes):
            lab = "star camera − fused" if (k == 0 and j == 0) else None
            ax.plot(sol.t, sol.sca_residual[:, j] / ARCSEC, ",", color="C0", label=lab)
            if truth is not None:
                lab = "fused − truth" if (k == 0 and j == 0) else None
                ax.plot(sol.t, truth.fused_error[k][:, j] / ARCSEC, lw=0.6, color="C3", label=lab)
    for j, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[j]} (arcsec)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", markerscale=20)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle("Attitude residuals per body axis")
    fig.tight_layout()
    out["residuals.png"] = figure_png(fig)

    fig, ax = plt.subplots(figsize=(9, 4))
    for k, sol in enumerate(run.solutions):
        for sigma, color, label in (
            (sol.epoch_sigma_sca, "C0", "star camera"),
            (sol.epoch_sigma_acc, "C1", "accelerometer"),
        ):
            ax.plot(sol.t, sigma, ".", ms=3, color=color, label=label if not k else None)
    ax.set_yscale("log")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("epoch sigma factor")
    ax.set_title("Huber epoch factors (1: full weight)")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    out["epoch_sigma.png"] = figure_png(fig)

    fig, axes = plt.subplots(1, 3, figsize=(12, 4), sharey=True)
    span = longest_star_camera_run(run)
    if span is not None:
        k, lo, hi = span
        sol, arc = run.solutions[k], run.arcs[k]
        for j, ax in enumerate(axes):
            if truth is not None:
                series = [
                    ("star camera alone − truth", truth.sca_error[k][lo:hi, j]),
                    ("fused − truth", truth.fused_error[k][lo:hi, j]),
                ]
            else:
                series = [("star camera − fused", sol.sca_residual[lo:hi, j])]
            for lab, x in series:
                f, asd = amplitude_spectral_density(x / ARCSEC, 1.0 / arc.dt, 4096)
                ax.loglog(f[1:], asd[1:], lw=0.8, label=lab)
            ax.set_title(f"axis {AXES[j]} (arc {k}, {sol.t[lo]:.6g}–{sol.t[hi - 1]:.6g} s)")
            ax.set_xlabel("frequency (Hz)")
            ax.grid(alpha=0.3, which="both")
        axes[0].set_ylabel("amplitude spectral density (arcsec/√Hz)")
        axes[0].legend(fontsize=8)
    fig.tight_layout()
    out["spectra.png"] = figure_png(fig)
    return out


def write_outputs(
    cfg: FusionConfig, run: FusionRun, out_dir: Path, source: str = "simulated"
) -> TruthComparison | None:
    """Compute every file, then write the folder atomically with its ``run.json`` (kind
    ``fuse``; ``source`` says where the data came from); returns the truth comparison."""
    truth = compare_with_truth(run)
    files = {
        "fused.csv": csv_text(FUSED_COLUMNS, fused_rows(run)),
        "variance_components.csv": csv_text(VC_COLUMNS, variance_rows(run)),
        "solution.csv": csv_text(SOLUTION_COLUMNS, solution_rows(run)),
        "epoch_sigma.csv": csv_text(EPOCH_SIGMA_COLUMNS, epoch_sigma_rows(run)),
        "acc_calibrated.csv": csv_text(ACC_COLUMNS, acc_rows(run)),
        "summary.md": summary_text(cfg, run, truth),
    }
    plots = _plots(run, truth)
    with staged_directory(out_dir) as stage:
        for name, text in files.items():
            atomic_write_text(stage / name, text)
        for name, data in plots.items():
            atomic_write_bytes(stage / name, data)
        write_manifest(stage, manifest("fuse", cfg.model_dump(mode="json"), source=source))
    return truth


__all__ = ["PLOTS", "TruthComparison", "compare_with_truth", "write_outputs"]
