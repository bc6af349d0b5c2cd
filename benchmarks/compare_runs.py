"""Compare two ``qkf bench`` folders number by number (docs/performance.md, "No number changed").

Run: ``.venv/bin/python benchmarks/compare_runs.py OLD_DIR NEW_DIR``: for rms.csv, the largest
absolute and relative difference of each state group per method; for summary.csv, the largest
relative difference of any metric. Both runs must have the same methods, epochs and trials.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from qkf.transfer_alignment.states import GROUPS, STATE_COLUMNS


def rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    args = ap.parse_args()
    a, b = rows(args.old / "rms.csv"), rows(args.new / "rms.csv")
    if len(a) != len(b):
        raise SystemExit(f"rms.csv: {len(a)} rows against {len(b)}")
    worst: dict[tuple[str, str], tuple[float, float]] = {}
    for ra, rb in zip(a, b, strict=True):
        if (ra["method"], ra["t_s"]) != (rb["method"], rb["t_s"]):
            raise SystemExit(f"rms.csv: row {ra['method']} {ra['t_s']} against {rb['method']}")
        for group, sl in GROUPS.items():
            for col in STATE_COLUMNS[sl]:
                x, y = float(ra[col]), float(rb[col])
                key = (ra["method"], group)
                d_abs, d_rel = worst.get(key, (0.0, 0.0))
                worst[key] = (max(d_abs, abs(x - y)), max(d_rel, abs(x - y) / max(abs(x), 1e-300)))
    print(f"{'method':22s} {'group':11s} {'max |Δ|':>10s} {'max rel':>10s}")
    for (method, group), (d_abs, d_rel) in worst.items():
        print(f"{method:22s} {group:11s} {d_abs:10.2e} {d_rel:10.2e}")
    sa, sb = rows(args.old / "summary.csv"), rows(args.new / "summary.csv")
    rel = 0.0
    for ra, rb in zip(sa, sb, strict=True):
        for col, text in ra.items():
            if col in ("method", "runtime_s") or not text or not rb[col]:
                continue
            xf, yf = float(text), float(rb[col])
            if xf == xf:  # not NaN
                rel = max(rel, abs(xf - yf) / max(abs(xf), 1e-300))
    print(f"summary.csv: max relative difference {rel:.2e}")


if __name__ == "__main__":
    main()
