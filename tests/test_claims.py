"""Claims studies: every run on the same trials, ratios of products of RMS values with paired
bootstrap intervals, verdicts by the interval; checked against a recomputation."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.claims import load_claims
from qkf.transfer_alignment.metrics import METRIC_COLUMNS

runner = CliRunner()
CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "transfer_alignment"
P, A = CONFIGS / "paper.yaml", CONFIGS / "attitude_only.yaml"

STUDY = f"""
name: tiny
kind: claims
trials: 4
seed: 2
resamples: 2000
claims:
  - id: a
    claim: rate matching beats attitude matching
    metric: ma_urad_final
    numerator: [{{base: {P}, set: [scenario.duration_s=200], method: kf}}]
    denominator: [{{base: {A}, set: [scenario.duration_s=200], method: kf}}]
  - id: b
    claim: a method against itself is inconclusive
    metric: att_arcsec_avg
    numerator:
      - {{base: {P}, set: [scenario.duration_s=200], method: kf}}
      - {{base: {A}, set: [scenario.duration_s=200], method: kf}}
    denominator:
      - {{base: {A}, set: [scenario.duration_s=200], method: kf}}
      - {{base: {P}, set: [scenario.duration_s=200], method: kf}}
"""


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_claims_study(tmp_path: Path) -> None:
    study = tmp_path / "claims.yaml"
    study.write_text(STUDY)
    out = tmp_path / "out"
    result = runner.invoke(app, ["study", str(study), "--out", str(out), "--quiet"])
    assert result.exit_code == 0, result.output
    rows = {r["claim_id"]: r for r in _rows(out / "claims.csv")}
    assert list(rows["a"]) == [
        "claim_id", "claim", "metric", "method", "baseline", "ratio", "lo", "hi", "verdict",
    ]  # fmt: skip
    # recompute claim a from the two benchmark folders' trials.csv
    folders = sorted(p for p in out.iterdir() if p.is_dir())
    assert len(folders) == 2
    by_name = {p.name.split("_")[0]: p for p in folders}
    j = METRIC_COLUMNS.index("ma_urad_final")

    def values(folder: Path) -> np.ndarray:
        return np.array([float(r[METRIC_COLUMNS[j]]) for r in _rows(folder / "trials.csv")])

    rate, att = values(by_name["paper"]), values(by_name["attitude"])
    ratio = np.sqrt(np.mean(rate**2)) / np.sqrt(np.mean(att**2))
    assert float(rows["a"]["ratio"]) == ratio
    lo, hi = float(rows["a"]["lo"]), float(rows["a"]["hi"])
    assert lo <= ratio <= hi
    expect = "reproduced" if hi < 1 else "refuted" if lo > 1 else "inconclusive"
    assert rows["a"]["verdict"] == expect
    # b is exactly 1 on every resample: the interval is [1, 1], neither below nor above
    assert float(rows["b"]["ratio"]) == 1.0 and rows["b"]["verdict"] == "inconclusive"
    assert "Why these metrics" in (out / "claims.md").read_text()


def test_paper_claims_preset_loads() -> None:
    study, configs = load_claims("paper_claims")
    assert [c.id for c in study.claims] == ["1", "2", "3", "4"]
    assert all(c.why for c in study.claims)
    assert len(configs) == 5


def test_bad_claim_is_refused(tmp_path: Path) -> None:
    study = tmp_path / "c.yaml"
    bad = STUDY.replace("method: kf}]\n  - id: b", "method: nosuch}]\n  - id: b")
    assert bad != STUDY
    study.write_text(bad)
    result = runner.invoke(app, ["study", str(study), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "claims.0.denominator.0.method" in result.output
    assert not (tmp_path / "o").exists()
