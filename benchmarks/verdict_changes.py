"""Which verdicts flipped between two families tables (issue 33, "What changed").

Reads an old and a new ``families.csv`` (``qkf study families``) and prints, as a Markdown
table, every (family, method) on ``state_settled`` whose verdict against the reference differs:
beats ↔ ties ↔ loses, with the old and the new numbers. A table written before per-trial
verdicts (no ``verdict`` column) is judged the way it was then: pooled interval only.

    python benchmarks/verdict_changes.py docs/evidence/families_seed9000/families.csv \\
        docs/evidence/families_issue33/families.csv
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from qkf.core.stats import ratio_side

WORDS = {"better": "beats", "worse": "loses", "inconclusive": "ties", "unjudged": "unjudged"}


def read(path: Path) -> dict[tuple[str, str], dict[str, str]]:
    """The ``state_settled`` rows of a families.csv by (family, method)."""
    with path.open(newline="") as f:
        return {
            (r["family"], r["method"]): r
            for r in csv.DictReader(f)
            if r["metric"] == "state_settled" and r["ratio_vs_kf_tuned"] != ""
        }


def verdict(row: dict[str, str]) -> str:
    """The row's verdict, or the pooled one of a table that has none."""
    if row.get("verdict"):
        return row["verdict"]
    side = ratio_side(float(row["ratio_lo"]), float(row["ratio_hi"]))
    return ("inconclusive", "worse", "better")[side]


def cell(row: dict[str, str]) -> str:
    text = f"{float(row['ratio_vs_kf_tuned']):.3f} [{float(row['ratio_lo']):.3f}, " + (
        f"{float(row['ratio_hi']):.3f}]"
    )
    if row.get("median_ratio"):
        text += (
            f"; median {float(row['median_ratio']):.3f} [{float(row['median_lo']):.3f}, "
            f"{float(row['median_hi']):.3f}], won {float(row['p_improve']):.0%}"
        )
    return text


def changes(old: Path, new: Path) -> list[str]:
    """The Markdown lines: a table of the flips, then the count of unchanged verdicts."""
    a, b = read(old), read(new)
    common = [k for k in a if k in b and k[1] != "kf-tuned"]
    lines = [
        "| family | method | before | after | old numbers (pooled) "
        "| new numbers (pooled; per trial) |",
        "|---|---|---|---|---|---|",
    ]
    same = 0
    for key in common:
        v_old, v_new = verdict(a[key]), verdict(b[key])
        if v_old == v_new:
            same += 1
            continue
        lines.append(
            f"| `{key[0]}` | `{key[1]}` | {WORDS[v_old]} | {WORDS[v_new]} | {cell(a[key])} | "
            f"{cell(b[key])} |"
        )
    lines += ["", f"{same} of {len(common)} verdicts unchanged."]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    args = ap.parse_args()
    print("\n".join(changes(args.old, args.new)))


if __name__ == "__main__":
    main()
