"""One policy against the key baselines on every family of a families study (issue 33).

Prints a Markdown table: per family, the policy ÷ each method on ``state_settled``, the pooled
RMS ratio / the median per-trial ratio and the verdict (both paired intervals on one side of 1;
docs/methods.md, "Per-trial verdicts"), from the case folders' ``trials.csv``, with the study's
own bootstrap (:func:`qkf.transfer_alignment.families.versus_rows`). A method that did not run
on a family (a shift family runs the ``-mixed`` twins only) is "–".

    python benchmarks/policy_versus.py results/families_issue33 ppo_mixed_v3
"""

from __future__ import annotations

import argparse
from pathlib import Path

from qkf.core.manifest import read_manifest
from qkf.transfer_alignment.families import versus_rows
from qkf.transfer_alignment.results import load_bench, read_trials_csv

VERSUS = (
    "kf-tuned", "kf-tuned-mixed", "clock", "clock-mixed", "glr", "nis-rule",
    "nis-rule-tuned-mixed", "hindsight",
)  # fmt: skip
WORDS = {"better": "**beats**", "worse": "loses", "inconclusive": "ties", "unjudged": "–"}


def table(study: Path, policy: str, versus: tuple[str, ...] = VERSUS) -> list[str]:
    """The Markdown lines of the table (module docstring)."""
    info = read_manifest(study, "study")
    seed = int(info["seed"])
    lines = [
        "| family | " + " | ".join(f"÷ {m}" for m in versus) + " |",
        "|---|" + "---|" * len(versus),
    ]
    for case in info["cases"]:
        folder = study / case["folder"]
        if not (folder / "run.json").is_file():  # a case not run (yet)
            continue
        boot = load_bench(folder).config.run.bootstrap
        values = read_trials_csv(folder)
        rows = {v.other: v for v in versus_rows(case["label"], values, [policy],
                                                boot.resamples, boot.level, seed)}  # fmt: skip
        cells = [
            "–" if (v := rows.get(m)) is None
            else f"{v.ratio:.3f} / {v.median:.3f} {WORDS[v.verdict]}"
            for m in versus
        ]  # fmt: skip
        lines.append(f"| `{case['label']}` | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("study", type=Path, help="a qkf study families output folder")
    ap.add_argument("policy", help="the policy's label in the study")
    args = ap.parse_args()
    print("\n".join(table(args.study, args.policy)))


if __name__ == "__main__":
    main()
