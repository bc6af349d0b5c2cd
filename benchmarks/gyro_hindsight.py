"""Does adaptation pay on the redundant-gyro calibration? Hindsight κ schedules against the best
constant κ, per episode of ``qkf/RedundantGyroCalibration-v1`` (docs/redundant_gyros.md,
"Hindsight").

For each episode (environment seed ``seed + i``: the same readings and truth as
``env.reset(seed=seed + i)``) the script scores, on the settled mean square ``J`` of the four
calibrated states over their prior sd (:mod:`qkf.redundant_gyros.hindsight`):

* every constant κ of the action set, and the best one over all the episodes (pooled);
* ``hindsight``: the episode's own best schedule, truth known (coordinate descent);
* ``level-informed``: the episode's own best constant κ, what a policy that identified the
  episode's noise levels (``scenario.onset.drift_scale``, ``noise_factor``) at once could hold;
* ``onset-informed``: κ_pre before the first period after the drawn onset, κ_post from it on,
  the pair best over all the episodes (it knows the onset time, nothing of the noise);
* with ``--control``, the same on the *control* scenario: the same config and seeds with the
  onset moved past the end of the run (no step, no drift; the same noise), which says how much
  of the hindsight gap is the noise of one episode, not the onset.

Ratios are RMS over episodes (``sqrt(Σ J_x / Σ J_y)``) with a paired percentile bootstrap 95 %
interval (episodes resampled jointly, :func:`qkf.core.stats.resample_counts`). Writes
``episodes.csv`` (one row per scenario and episode), ``ratios.csv`` and ``summary.md`` under
``--out``.

    python benchmarks/gyro_hindsight.py --episodes 64 --control --out results/gyro_hindsight
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qkf.core.stats import bootstrap_rms, percentile_interval, resample_counts
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.config import GyrosConfig

CONTROL = "scenario.onset.onset_s=[1e12,1e12]"
"""The control: the onset (and with it the step and the onset-started drift) past the end."""


@dataclass
class Scores:
    """Per-episode ``J`` of one scenario (E episodes, A actions)."""

    seeds: np.ndarray  # (E,)
    onset_s: np.ndarray  # (E,) s, NaN without an onset
    constant: np.ndarray  # (E, A)
    hindsight: np.ndarray  # (E,)
    two_level: np.ndarray  # (E, A, A)
    schedules: list[str]  # hindsight action per period, one hex digit each
    seconds: float


def score_episodes(cfg: GyrosConfig, seeds: np.ndarray, settled_s: float) -> Scores:
    """Constant, hindsight and onset-informed ``J`` of the episodes ``seeds``."""
    tic = time.perf_counter()
    const, hind, two, onsets, scheds = [], [], [], [], []
    for seed in seeds:
        ep = hs.episode(cfg, int(seed), settled_s)
        res = hs.search(ep)
        const.append(res.constant_scores)
        hind.append(res.score)
        two.append(hs.two_level_scores(ep))
        onsets.append(np.nan if ep.inputs.onset_s is None else ep.inputs.onset_s)
        scheds.append("".join(f"{c:x}" for c in res.choice))
    return Scores(
        seeds=seeds,
        onset_s=np.array(onsets),
        constant=np.array(const),
        hindsight=np.array(hind),
        two_level=np.array(two),
        schedules=scheds,
        seconds=time.perf_counter() - tic,
    )


def paired_ratio(
    num: np.ndarray, den: np.ndarray, counts: np.ndarray, level: float = 0.95
) -> tuple[float, float, float]:
    """``sqrt(Σ num / Σ den)`` of per-episode mean squares and its paired percentile interval
    over the resamples ``counts`` (R, E)."""
    ratio = float(np.sqrt(np.sum(num) / np.sum(den)))
    boot = bootstrap_rms(num, counts) / bootstrap_rms(den, counts)
    lo, hi = percentile_interval(boot, level)
    return ratio, float(lo), float(hi)


def comparisons(s: Scores, kappas: np.ndarray, counts: np.ndarray) -> list[dict[str, object]]:
    """The ratio rows of one scenario."""
    best = hs.best_constant(s.constant)
    flat = s.two_level.reshape(s.two_level.shape[0], -1)
    pair = int(np.argmin(np.mean(flat, axis=0)))
    pre, post = divmod(pair, kappas.size)
    nominal = int(np.argmin(np.abs(np.log(kappas))))
    c = s.constant[:, best]
    rows = [
        ("hindsight / best constant", s.hindsight, c),
        (
            f"onset-informed (κ {kappas[pre]:.3g} → {kappas[post]:.3g}) / best constant",
            flat[:, pair],
            c,
        ),
        ("κ = 1 (nominal) / best constant", s.constant[:, nominal], c),
        # the episode's own best constant: a policy that identified the episode's noise levels
        # at once and held the κ they match (it knows nothing of the onset)
        ("level-informed (own best constant) / best constant", s.constant.min(axis=1), c),
        ("hindsight / onset-informed", s.hindsight, flat[:, pair]),
    ]
    out: list[dict[str, object]] = []
    for name, num, den in rows:
        r, lo, hi = paired_ratio(num, den, counts)
        out.append({"comparison": name, "ratio": r, "lo": lo, "hi": hi})
    out.append(
        {
            "comparison": f"best constant κ = {kappas[best]:.3g}",
            "ratio": np.nan,
            "lo": np.nan,
            "hi": np.nan,
        }
    )
    return out


def _write_csv(path: Path, header: list[str], rows: list[list[object]]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    with tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="five_gyros_onset_drift", help="gyro preset or path")
    ap.add_argument("--set", dest="overrides", action="append", default=[], help="KEY=VALUE")
    ap.add_argument("--episodes", type=int, default=32)
    ap.add_argument("--seed", type=int, default=5_000_000, help="first environment seed")
    ap.add_argument("--settled-s", type=float, default=hs.SETTLED_S)
    ap.add_argument("--resamples", type=int, default=10_000)
    ap.add_argument("--control", action="store_true", help="also the no-onset control")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    if a.episodes < 2:
        ap.error("--episodes: at least 2")
    scenarios = {"onset": load_config(a.config, a.overrides)}
    if a.control:
        scenarios["control"] = load_config(a.config, [*a.overrides, CONTROL])
    seeds = np.arange(a.seed, a.seed + a.episodes)
    counts = resample_counts(a.episodes, a.resamples, a.seed)
    a.out.mkdir(parents=True, exist_ok=True)
    ep_rows: list[list[object]] = []
    ratio_rows: list[list[object]] = []
    gaps: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    lines = [
        "# Gyro hindsight: does adaptation pay?",
        "",
        f"`{a.config}` {' '.join(a.overrides)}; {a.episodes} episodes, seeds {a.seed}…"
        f"{a.seed + a.episodes - 1}; settled from {a.settled_s:g} s; criterion J = settled "
        "mean square of [b, λ, δ_u, δ_v] over their prior sd; ratios of RMS over episodes, "
        f"paired bootstrap 95 % ({a.resamples} resamples).",
        "",
        "| scenario | comparison | ratio | 95 % interval |",
        "|---|---|---|---|",
    ]
    kappas = np.asarray(scenarios["onset"].environment.actions.values(), dtype=float)
    for name, cfg in scenarios.items():
        s = score_episodes(cfg, seeds, a.settled_s)
        gaps[name] = (s.hindsight, s.constant[:, hs.best_constant(s.constant)])
        for i in range(a.episodes):
            ep_rows.append(
                [
                    name,
                    int(s.seeds[i]),
                    s.onset_s[i],
                    *s.constant[i],
                    s.hindsight[i],
                    s.schedules[i],
                ]
            )
        for row in comparisons(s, kappas, counts):
            ratio_rows.append([name, row["comparison"], row["ratio"], row["lo"], row["hi"]])
            if np.isfinite(float(row["ratio"])):  # type: ignore[arg-type]
                lines.append(
                    f"| {name} | {row['comparison']} | {row['ratio']:.3f} | "
                    f"[{row['lo']:.3f}, {row['hi']:.3f}] |"
                )
            else:
                lines.append(f"| {name} | {row['comparison']} | | |")
        mean_j = np.mean(s.constant, axis=0)
        lines.append(
            f"| {name} | mean J per constant κ / best | "
            + " ".join(
                f"{k:.3g}:{m / mean_j.min():.3f}" for k, m in zip(kappas, mean_j, strict=True)
            )
            + f" | {s.seconds:.1f} s ({s.seconds / a.episodes:.2f} s an episode) |"
        )
    if "control" in gaps:
        (n_on, d_on), (n_co, d_co) = gaps["onset"], gaps["control"]
        boot = (bootstrap_rms(n_on, counts) / bootstrap_rms(d_on, counts)) / (
            bootstrap_rms(n_co, counts) / bootstrap_rms(d_co, counts)
        )
        point = float(np.sqrt(n_on.sum() / d_on.sum()) / np.sqrt(n_co.sum() / d_co.sum()))
        lo, hi = percentile_interval(boot)
        what = "(hindsight / best constant) onset ÷ control"
        ratio_rows.append(["both", what, point, float(lo), float(hi)])
        lines.append(f"| both | {what} | {point:.3f} | [{float(lo):.3f}, {float(hi):.3f}] |")
    header = [
        "scenario",
        "seed",
        "onset_s",
        *(f"J_kappa_{k:.3g}" for k in kappas),
        "J_hindsight",
        "schedule",
    ]
    _write_csv(a.out / "episodes.csv", header, ep_rows)
    _write_csv(a.out / "ratios.csv", ["scenario", "comparison", "ratio", "lo", "hi"], ratio_rows)
    (a.out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
