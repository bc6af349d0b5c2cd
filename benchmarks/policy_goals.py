"""The issue-21 goals of a learned κ policy, checked on a families study (``qkf zoo evaluate``
or ``qkf study families`` with the policy among its methods).

Per family, on the study's per-trial table, paired over the same bootstrap resamples of trials
(:func:`qkf.core.stats.resample_counts`), RMS over trials of ``state_settled`` and of each
state group's settled RMS:

1. the policy against the best of the baselines (``kf-tuned``, ``clock``, ``glr``,
   ``alarm-burst`` and every ``*-tuned`` method that ran; the best by point RMS on the
   family): the interval's upper end below 1 on every family with a change;
2. against ``clock``: upper end ≤ 0.99 on at least three families;
3. on ``steady_random``: upper end ≤ 1.02 × ``kf-tuned``;
4. no state group (attitude, bias, scale factor, misalignment) more than 5 % worse than
   ``kf-tuned`` on any family (upper end ≤ 1.05);
5. with ``--hindsight DIR``, a families study on the same benchmark seed that ran
   ``hindsight`` (10 s a trial, so the entry's study leaves it out): the share of the
   ``kf-tuned → hindsight`` gap the policy closes, ``(RMS_kf-tuned − RMS_policy) /
   (RMS_kf-tuned − RMS_hindsight)`` over the trials both ran (trials are reproducible from
   ``(seed, trial)``, so they are the same trials: every method both ran must agree on them,
   which is checked), goal ≥ 0.5 on the families with a change;
6. over training seeds (labels ``NAME#SEED``): rliable's IQM of the per-trial score
   ``RMS_kf-tuned / RMS_policy`` on ``mixed_random``, its interval above 1 (the study's own
   ``seed_statistics``).

    python benchmarks/policy_goals.py --study results/zoo/NAME/families --policy 'NAME#2' \\
        --hindsight results/families_seed9000 --out goals.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from qkf.core.seed_groups import SEED_MARK
from qkf.core.stats import bootstrap_rms, percentile_interval, resample_counts
from qkf.transfer_alignment.families import seed_statistics
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED
from qkf.transfer_alignment.results import read_trials_csv
from qkf.transfer_alignment.states import GROUPS

NAMED = ("kf-tuned", "clock", "glr", "alarm-burst")
STEADY = "steady_random"
GROUP_COLUMNS = {g: f"{g}_settled" for g in GROUPS}
RESAMPLES = 4000
LEVEL = 0.95


def _ratio(a: np.ndarray, b: np.ndarray, counts: np.ndarray) -> tuple[float, float, float]:
    """RMS(a) / RMS(b) over trials, and its paired percentile interval."""
    point = float(np.sqrt(np.mean(a**2) / np.mean(b**2)))
    lo, hi = percentile_interval(bootstrap_rms(a**2, counts) / bootstrap_rms(b**2, counts), LEVEL)
    return point, float(lo), float(hi)


def _cell(r: tuple[float, float, float]) -> str:
    return f"{r[0]:.3f} [{r[1]:.3f}, {r[2]:.3f}]"


def family_goals(
    family: str, values: dict[str, np.ndarray], policy: str, seed: int = 0
) -> tuple[list[str], dict[str, bool]]:
    """Markdown rows and the pass/fail of goals 1–4 on one family."""
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    n = values[policy].shape[0]
    counts = resample_counts(n, RESAMPLES, seed)
    pol = values[policy][:, j]
    baselines = [
        m for m in values
        if SEED_MARK not in m and (m in NAMED or m.endswith("-tuned"))
    ]  # fmt: skip
    best = min(baselines, key=lambda m: float(np.mean(values[m][:, j] ** 2)))
    vs_best = _ratio(pol, values[best][:, j], counts)
    vs_clock = _ratio(pol, values["clock"][:, j], counts) if "clock" in values else None
    vs_ref = _ratio(pol, values["kf-tuned"][:, j], counts)
    groups = {
        g: _ratio(values[policy][:, METRIC_COLUMNS.index(c)],
                  values["kf-tuned"][:, METRIC_COLUMNS.index(c)], counts)
        for g, c in GROUP_COLUMNS.items()
    }  # fmt: skip
    worst_group = max(groups, key=lambda g: groups[g][2])
    ok = {
        "beats_best": vs_best[2] < 1.0,
        "clock_099": vs_clock is not None and vs_clock[2] <= 0.99,
        "steady_102": vs_ref[2] <= 1.02,
        "groups_105": all(r[2] <= 1.05 for r in groups.values()),
    }
    row = (
        f"| {family} | {n} | {_cell(vs_ref)} | {_cell(vs_best)} (`{best}`) | "
        + (_cell(vs_clock) if vs_clock else "–")
        + f" | {worst_group} {_cell(groups[worst_group])} |"
    )
    return [row], ok


def gap_closed(
    ref: np.ndarray, policy: np.ndarray, yard: np.ndarray, counts: np.ndarray
) -> tuple[float, float, float]:
    """The closed share of the ``ref → yard`` gap by ``policy`` (per-trial values on the same
    trials), and its paired interval over the resamples ``counts``."""
    r, p, h = (np.sqrt(np.mean(x**2)) for x in (ref, policy, yard))
    rr, pp, hh = (bootstrap_rms(x**2, counts) for x in (ref, policy, yard))
    with np.errstate(divide="ignore", invalid="ignore"):
        lo, hi = percentile_interval((rr - pp) / (rr - hh), LEVEL)
    return float((r - p) / (r - h)), float(lo), float(hi)


def hindsight_gap(
    study: Path, hindsight: Path, family: str, new: dict[str, np.ndarray], policy: str
) -> tuple[int, tuple[float, float, float]] | None:
    """Goal 5 on one family: (shared trials, closed share); None without hindsight there.
    ``ValueError`` if the two studies disagree on a method both ran (not the same trials)."""
    if not (hindsight / family / "trials.csv").is_file():
        return None
    old = read_trials_csv(hindsight / family)
    if "hindsight" not in old:
        return None
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    n = min(new[policy].shape[0], old["hindsight"].shape[0])  # trials 0 … n − 1 of both
    for m in set(new) & set(old):
        if not np.allclose(new[m][:n, j], old[m][:n, j], rtol=1e-9, atol=0.0):
            raise ValueError(f"{family}: {m} differs between {study} and {hindsight}")
    counts = resample_counts(n, RESAMPLES, 1)
    return n, gap_closed(
        new["kf-tuned"][:n, j], new[policy][:n, j], old["hindsight"][:n, j], counts
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", type=Path, required=True, help="a families study folder")
    ap.add_argument("--policy", required=True, help="the policy's method label in the study")
    ap.add_argument("--hindsight", type=Path, help="a families study that ran hindsight")
    ap.add_argument("--out", type=Path, required=True, help="markdown file to write")
    args = ap.parse_args(argv)
    if args.out.exists():
        print(f"{args.out}: exists; not overwritten", file=sys.stderr)
        return 2
    families = sorted(p.name for p in args.study.iterdir() if (p / "trials.csv").is_file())
    lines = [
        f"# Goals of `{args.policy}` on `{args.study}`",
        "",
        "RMS over trials of `state_settled` (group: settled RMS of the group), policy ÷ method, "
        f"paired percentile {100 * LEVEL:g} % interval over {RESAMPLES} resamples of trials.",
        "",
        "| family | trials | ÷ kf-tuned | ÷ best baseline | ÷ clock | worst group ÷ kf-tuned "
        "| kf-tuned → hindsight gap closed (trials) |",
        "|---|---|---|---|---|---|---|",
    ]
    verdict: dict[str, list[str]] = {
        k: [] for k in ("beats_best", "clock_099", "groups_105", "half_gap")
    }
    steady_ok = None
    iqm_line = ""
    for family in families:
        values = read_trials_csv(args.study / family)
        if args.policy not in values:
            continue
        rows, ok = family_goals(family, values, args.policy)
        gap = (
            hindsight_gap(args.study, args.hindsight, family, values, args.policy)
            if args.hindsight is not None
            else None
        )
        lines += [rows[0] + (f" {_cell(gap[1])} ({gap[0]}) |" if gap else " – |")]
        if gap is not None and family != STEADY and gap[1][0] >= 0.5:
            verdict["half_gap"].append(family)
        if family == STEADY:
            steady_ok = ok["steady_102"]
        else:
            if ok["beats_best"]:
                verdict["beats_best"].append(family)
            if ok["clock_099"]:
                verdict["clock_099"].append(family)
        if ok["groups_105"]:
            verdict["groups_105"].append(family)
        if family == "mixed_random":
            for stat in seed_statistics(values, ["kf-tuned"], LEVEL):
                if str(stat["policy"]) == args.policy.partition(SEED_MARK)[0]:
                    iqm_line = (
                        f"IQM over {stat['seeds']} seeds × trials of RMS_kf-tuned / RMS_policy "
                        f"on mixed_random: {stat['iqm']:.3f} [{stat['iqm_lo']:.3f}, "
                        f"{stat['iqm_hi']:.3f}] (goal: the interval above 1)"
                    )
    changed = [f for f in families if f != STEADY]
    lines += [
        "",
        f"- beats the best baseline (upper end < 1) on {len(verdict['beats_best'])} of "
        f"{len(changed)} families with a change: {', '.join(verdict['beats_best']) or 'none'}",
        f"- ÷ clock upper end ≤ 0.99 on {len(verdict['clock_099'])} families (goal ≥ 3): "
        f"{', '.join(verdict['clock_099']) or 'none'}",
        f"- steady_random ÷ kf-tuned upper end ≤ 1.02: {steady_ok}",
        f"- no group > 5 % worse than kf-tuned on {len(verdict['groups_105'])} of "
        f"{len(families)} families",
        f"- half of the kf-tuned → hindsight gap closed on {len(verdict['half_gap'])} of "
        f"{len(changed)} families with a change: {', '.join(verdict['half_gap']) or 'none'}"
        + ("" if args.hindsight else " (no --hindsight study)"),
        f"- {iqm_line}" if iqm_line else "- no seed statistics (one training seed?)",
    ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
