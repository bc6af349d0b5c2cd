"""Output files of ``qkf align`` (docs/alignment.md, "Output").

``alignment.csv`` (one row per sensor: ``θ`` and its 1-σ per body axis, µrad; the reference is
zero), ``observability.csv`` (the eigen-directions of the data information, weakest first),
``summary.md``, ``residuals.png`` and, for a simulated run, ``data.csv`` (the simulated input,
to be fed back with ``--data``). Everything is rendered in memory first; :func:`write_outputs`
writes the folder in one piece.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy import stats

from qkf.alignment.config import AlignmentConfig
from qkf.alignment.data import Observations, write_data_text
from qkf.alignment.solve import Direction, Solution
from qkf.core import units
from qkf.core.io import atomic_write_bytes, atomic_write_text, csv_text, staged_directory
from qkf.core.manifest import manifest, write_manifest

ALIGNMENT_COLUMNS = (
    "sensor",
    "theta_x_urad",
    "theta_y_urad",
    "theta_z_urad",
    "sd_x_urad",
    "sd_y_urad",
    "sd_z_urad",
)


def alignment_csv(sol: Solution) -> str:
    rows = [
        [
            name,
            *(float(v) for v in sol.theta[i] / units.URAD),
            *(float(v) for v in sol.sd[i] / units.URAD),
        ]
        for i, name in enumerate(sol.names)
    ]
    return csv_text(ALIGNMENT_COLUMNS, rows)


def observability_csv(sol: Solution) -> str:
    free_names = [sol.names[i] for i in sol.free]
    header = [
        "direction",
        "data_information_scaled",
        "relative_to_largest",
        "data_information_per_rad2",
        "prior_information_per_rad2",
        "sd_urad",
        "prior_sd_urad",
        "rank_deficient",
        "prior_determined",
        *(f"{n}_{ax}" for n in free_names for ax in "xyz"),
    ]
    rows = []
    for k, d in enumerate(sol.directions, start=1):
        rows.append(
            [
                k,
                d.scaled,
                d.relative,
                d.information,
                d.prior_information,
                d.sd / units.URAD,
                d.prior_sd / units.URAD,
                str(d.rank_deficient).lower(),
                str(d.prior_determined).lower(),
                *(float(v) for v in d.vector),
            ]
        )
    return csv_text(header, rows)


def _fmt(v: float, digits: int = 4) -> str:
    return f"{v:.{digits}g}"


def _vec(v: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:+.3f}" for x in v) + "]"


def _boresight_angle(cfg: AlignmentConfig, name: str, axis: np.ndarray) -> float:
    b = np.asarray(cfg.sensors[cfg.names.index(name)].boresight, dtype=float)
    c = abs(float(axis @ b)) / float(np.linalg.norm(b))
    return float(np.degrees(np.arccos(min(1.0, c))))


def describe_direction(cfg: AlignmentConfig, d: Direction) -> str:
    """One line naming a direction: the rotation axis of each sensor it involves."""
    parts = [
        f"{name} about body axis {_vec(axis)} ({_boresight_angle(cfg, name, axis):.1f}° from its "
        f"boresight{'' if share > 0.999 else f', {share:.0%} of the direction'})"
        for name, axis, share in d.axes
    ]
    return "; ".join(parts)


def summary_md(
    cfg: AlignmentConfig,
    obs: Observations,
    sol: Solution,
    truth: np.ndarray | None,
    source: str,
) -> str:
    u = units.URAD
    lines = [f"# qkf align: {cfg.name}", ""]
    if cfg.description:
        lines += [cfg.description, ""]
    lines += [
        f"Input: {source}. Reference (body frame): **{cfg.reference}**. "
        f"{obs.n} observations; {sol.n_pairs} pairs at {sol.n_epochs} epochs, "
        f"{sol.rows} independent whitened rows (the pairs of one epoch are correlated and at most "
        f"2m − 3 of them are independent for m vectors: a common rotation changes no angle).",
        "",
        "| sensor | σ [arcsec] | prior [deg] | observations |",
        "|---|---|---|---|",
    ]
    counts = np.bincount(obs.sensor, minlength=len(cfg.sensors))
    for i, s in enumerate(cfg.sensors):
        prior = "– (reference)" if s.name == cfg.reference else _fmt(cfg.prior_deg_of(s))
        lines.append(f"| {s.name} | {_fmt(s.sigma_arcsec)} | {prior} | {counts[i]} |")
    conv = "converged" if sol.converged else "**not converged**"
    steps = ", ".join(f"{s:.3g}" for s in sol.steps)
    lines += [
        "",
        "## Solution",
        "",
        f"Gauss–Newton: {sol.iterations} iterations, {conv} (largest step component / its σ per "
        f"iteration: {steps}; tolerance {cfg.solver.tolerance:g}). Pair weighting: "
        + (
            "full per-epoch covariance."
            if cfg.solver.correlated_pairs
            else "each pair's own variance only (`solver.correlated_pairs: false`)."
        ),
        "",
        "| sensor | θx [µrad] | θy [µrad] | θz [µrad] | σx [µrad] | σy [µrad] | σz [µrad] "
        "| prior share x / y / z |",
        "|---|---|---|---|---|---|---|---|",
    ]
    share = sol.prior_share
    for i, name in enumerate(sol.names):
        th = " | ".join(f"{v:.2f}" for v in sol.theta[i] / u)
        sd = " | ".join(f"{v:.3g}" for v in sol.sd[i] / u)
        ps = "–" if name == sol.reference else " / ".join(f"{v:.2g}" for v in share[i])
        lines.append(f"| {name} | {th} | {sd} | {ps} |")
    lines += [
        "",
        "*prior share*: posterior variance / prior variance of the component (near 1: the prior "
        "alone fixes it).",
        "",
        "## Observability",
        "",
    ]
    weak = sol.unobservable()
    lines.append(
        f"Rank of the data information: **{sol.rank} of {sol.n_unknowns}** (eigenvalues of the "
        f"prior-scaled information below {cfg.observability.rank_tolerance:g} × the largest count "
        f"as zero). Directions where the prior supplies more than "
        f"{cfg.observability.prior_share:.0%} of the information are flagged *prior-determined*."
    )
    lines.append("")
    if weak:
        lines.append(f"**{len(weak)} direction(s) not determined by the data:**")
        lines.append("")
        for d in weak:
            flags = " and ".join(
                f
                for f, on in (
                    ("rank-deficient", d.rank_deficient),
                    ("prior-determined", d.prior_determined),
                )
                if on
            )
            lines.append(
                f"- {flags}: {describe_direction(cfg, d)}. Data information "
                f"{d.information:.3g} /rad² (×{d.relative:.2g} of the strongest direction) "
                f"against the prior's {d.prior_information:.3g} /rad²; the estimate along it is "
                f"the prior's (σ {d.sd / u:.4g} µrad, prior σ {d.prior_sd / u:.4g} µrad), not the "
                "data's."
            )
    else:
        lines.append("Every direction is determined by the data.")
    lines += [
        "",
        "| # | data / prior information | relative | σ [µrad] | direction |",
        "|---|---|---|---|---|",
    ]
    for k, d in enumerate(sol.directions, start=1):
        lines.append(
            f"| {k} | {d.scaled:.3g} | {d.relative:.2g} | {d.sd / u:.4g} | "
            f"{describe_direction(cfg, d)} |"
        )
    lines += [
        "",
        "## Residuals",
        "",
        f"Whitened residuals at the solution: χ² = {sol.chi2:.1f} over {sol.rows} rows "
        f"(χ²/rows = {sol.chi2 / max(sol.rows, 1):.3f}; 1 when the noise model fits).",
        "",
        "| pair | pairs | RMS angle [arcsec] | RMS normalised |",
        "|---|---|---|---|",
    ]
    norm = sol.z / np.where(sol.z_sd > 0, sol.z_sd, np.inf)
    for k, label in enumerate(sol.pair_types):
        sel = sol.pair_type == k
        rms_angle = float(np.sqrt(np.mean(sol.angle[sel] ** 2))) / units.ARCSEC
        rms_norm = float(np.sqrt(np.mean(norm[sel] ** 2)))
        lines.append(f"| {label} | {int(sel.sum())} | {rms_angle:.3g} | {rms_norm:.3f} |")
    if truth is not None:
        err = sol.theta - truth
        e = err[sol.free].ravel()
        nees = float(e @ np.linalg.solve(sol.cov, e))
        lo, hi = stats.chi2.ppf([0.025, 0.975], sol.n_unknowns)
        lines += [
            "",
            "## Errors against the simulated truth",
            "",
            "| sensor | true θ [µrad] | error [µrad] | error / σ |",
            "|---|---|---|---|",
        ]
        for i in sol.free:
            ratio = err[i] / sol.sd[i]
            lines.append(
                f"| {sol.names[i]} | {_vec(truth[i] / u)} | {_vec(err[i] / u)} | {_vec(ratio)} |"
            )
        lines += [
            "",
            f"NEES = {nees:.2f} for {sol.n_unknowns} unknowns (95 % band of χ²: "
            f"[{lo:.2f}, {hi:.2f}]).",
        ]
    return "\n".join(lines) + "\n"


def residual_plot(sol: Solution) -> bytes:
    from qkf.core.plotting import figure_png, plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4), gridspec_kw={"width_ratios": [2, 1]})
    norm = sol.z / np.where(sol.z_sd > 0, sol.z_sd, np.inf)
    for k, label in enumerate(sol.pair_types):
        sel = sol.pair_type == k
        ax1.plot(sol.pair_t[sel], norm[sel], ".", ms=3, alpha=0.6, label=label)
    ax1.axhline(0.0, color="k", lw=0.5)
    ax1.set_xlabel("t [s]")
    ax1.set_ylabel("residual / σ")
    ax1.set_title("pair residuals at the solution")
    ax1.legend(fontsize=8, markerscale=3)
    ax2.hist(norm, bins=60, density=True, alpha=0.6, label="residual / σ")
    grid = np.linspace(-4.5, 4.5, 200)
    ax2.plot(grid, stats.norm.pdf(grid), "k-", lw=1, label="N(0, 1)")
    ax2.set_xlim(-5, 5)
    ax2.legend(fontsize=8)
    ax2.set_title("distribution")
    fig.tight_layout()
    return figure_png(fig)


def write_outputs(
    out_dir: str | Path,
    cfg: AlignmentConfig,
    obs: Observations,
    sol: Solution,
    truth: np.ndarray | None,
    source: str,
    plot: bool = True,
) -> list[Path]:
    """Render every file, then write the folder atomically with its ``run.json`` (kind
    ``align``), replacing ``out_dir`` whole."""
    files: dict[str, str | bytes] = {
        "alignment.csv": alignment_csv(sol),
        "observability.csv": observability_csv(sol),
        "summary.md": summary_md(cfg, obs, sol, truth, source),
    }
    if truth is not None:
        files["data.csv"] = write_data_text(obs)
    if plot:
        files["residuals.png"] = residual_plot(sol)
    with staged_directory(out_dir) as stage:
        for name, content in files.items():
            if isinstance(content, bytes):
                atomic_write_bytes(stage / name, content)
            else:
                atomic_write_text(stage / name, content)
        write_manifest(stage, manifest("align", cfg.model_dump(mode="json"), source=source))
    return [Path(out_dir) / name for name in (*files, "run.json")]
