"""The room in v4's action space (issue 34): per family of a families study, the best classical
method against the hindsight over the moves, and policies against both.

Per family (the case folders' ``trials.csv``, ``state_settled``):

* **best classical**: the method of lowest pooled RMS among the study's flight methods (every
  method but the yardsticks, ``hindsight…``, ``oracle``, ``clock…``, and the policies given);
* **room**: ``hindsight-moves:…`` ÷ best classical, pooled RMS ratio and median per-trial
  ratio with their paired 95 % bootstrap intervals (the study's own,
  :func:`qkf.transfer_alignment.families.versus_rows`), and the stage means of its note (κ
  alone, then the other moves);
* each policy ÷ best classical, with the verdict, and the share of the gap it closes,
  ``(RMS_best − RMS_policy) / (RMS_best − RMS_hindsight-moves)``.

    python benchmarks/v4_room.py results/v4_room --policies resid_glr#0,resid_glr#1
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from qkf.core.manifest import read_manifest
from qkf.transfer_alignment.families import versus_rows
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED
from qkf.transfer_alignment.results import load_bench, read_trials_csv

YARDSTICK_PREFIXES = ("hindsight", "oracle", "clock")
WORDS = {"better": "**beats**", "worse": "loses", "inconclusive": "ties", "unjudged": "–"}


def pooled(values: dict[str, np.ndarray], method: str) -> float:
    """RMS over trials of a method's per-trial ``state_settled``."""
    return float(np.sqrt(np.mean(np.square(values[method]))))


def stage_means(folder: Path, label: str) -> str:
    """The stage means of ``label``'s ``hindsight-moves`` note in the case's summary.md."""
    text = (folder / "summary.md").read_text()
    for line in text.splitlines():
        if line.startswith(f"- {label}: per-trial best schedule of the moves"):
            found = re.search(r"state_settled (.*?);", line)
            return found.group(1) if found else ""
    return ""


def table(study: Path, policies: list[str], room: Path | None = None) -> list[str]:
    """The Markdown lines; ``room``: another families study on the same trials (seed, trials)
    whose ``hindsight-moves`` column is used where ``study`` has none."""
    info = read_manifest(study, "study")
    seed = int(info["seed"])
    lines = [
        "| family | best classical (RMS) | hindsight-moves ÷ best: pooled / median | "
        "hindsight-moves stages (mean per trial) | "
        + " | ".join(f"{p} ÷ best; share of the gap" for p in policies)
        + " |",
        "|---|---|---|---|" + "---|" * len(policies),
    ]
    for case in info["cases"]:
        folder = study / case["folder"]
        if not (folder / "run.json").is_file():
            continue
        boot = load_bench(folder).config.run.bootstrap
        rows = read_trials_csv(folder)
        other = None if room is None else room / case["folder"]
        if other is not None and (other / "trials.csv").is_file():
            for m, v in read_trials_csv(other).items():
                if m.startswith("hindsight-moves") and m not in rows:
                    rows[m] = v  # the same trials: the study's seed and trial count
        j = METRIC_COLUMNS.index(STATE_SETTLED)
        values = {m: v[:, j] for m, v in rows.items()}
        moves = next((m for m in values if m.startswith("hindsight-moves")), None)
        classical = [
            m for m in values if not m.startswith(YARDSTICK_PREFIXES) and m not in policies
            and not m.startswith("policy:")
        ]  # fmt: skip
        best = min(classical, key=lambda m: pooled(values, m))
        focus = [m for m in [moves, *policies] if m is not None and m in values]
        versus = {
            row.method: row
            for row in versus_rows(case["label"], rows, focus, boot.resamples, boot.level, seed)
            if row.other == best
        }
        cells = [f"`{best}` ({pooled(values, best):.4g})"]
        if moves is not None and moves in versus:
            vs = versus[moves]
            cells.append(f"{vs.ratio:.3f} / {vs.median:.3f} {WORDS[vs.verdict]}")
            cells.append(stage_means(folder if other is None else other, moves))
        else:
            cells += ["–", "–"]
        for p in policies:
            if p not in versus:
                cells.append("–")
                continue
            vs = versus[p]
            share = "–"
            if moves is not None:
                gap = pooled(values, best) - pooled(values, moves)
                if gap > 0:
                    share = f"{(pooled(values, best) - pooled(values, p)) / gap:.0%}"
            cells.append(f"{vs.ratio:.3f} / {vs.median:.3f} {WORDS[vs.verdict]}; {share}")
        lines.append(f"| `{case['label']}` | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("study", type=Path, help="a qkf study families output folder")
    ap.add_argument("--policies", default="", help="policy labels, comma-separated")
    ap.add_argument("--room", type=Path, help="a study with hindsight-moves on the same trials")
    args = ap.parse_args()
    policies = [p for p in args.policies.split(",") if p]
    print("\n".join(table(args.study, policies, args.room)))


if __name__ == "__main__":
    main()
