"""Statistics of a benchmark: summary.csv follows from trials.csv exactly; the intervals are
percentile bootstraps over trials, paired across methods; checked by an independent
recomputation, a hand example and a coverage experiment."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core.stats import bootstrap_rms, percentile_interval, percentiles, resample_counts
from qkf.core.versus import paired_verdict, versus_rows
from qkf.transfer_alignment.metrics import METRIC_COLUMNS, recovery_times

runner = CliRunner()


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("stats") / "run"
    result = runner.invoke(
        app,
        ["bench", "thermal_snap", "--methods", "kf,qkf,sage-husa", "--trials", "12", "--seed",
         "3", "--out", str(out), "--quiet", "--set", "scenario.duration_s=600",
         "--set", "scenario.calibration_jumps.0.t_s=450", "--set", "run.chunk_trials=5",
         "--set", "run.bootstrap.resamples=4000"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def _trial_values(run: Path) -> dict[str, np.ndarray]:
    per: dict[str, list[list[float]]] = {}
    for r in _rows(run / "trials.csv"):
        per.setdefault(r["method"], []).append([float(r[c]) for c in METRIC_COLUMNS])
    return {m: np.array(v) for m, v in per.items()}


@pytest.mark.slow  # the module's 12-trial benchmark (fixture run)
def test_summary_follows_from_trials_exactly(run: Path) -> None:
    values = _trial_values(run)
    for r in _rows(run / "summary.csv"):
        v = values[r["method"]]
        assert v.shape == (12, len(METRIC_COLUMNS))
        for j, col in enumerate(METRIC_COLUMNS):
            assert float(r[col]) == float(np.sqrt(np.mean(v[:, j] ** 2)))
            assert float(r[f"{col}_lo"]) <= float(r[col]) <= float(r[f"{col}_hi"])


@pytest.mark.slow  # the module's 12-trial benchmark (fixture run)
def test_paired_interval_recomputed_independently(run: Path) -> None:
    """An index-based paired bootstrap written here, with other resamples, agrees with
    paired.csv to within the Monte Carlo error of 4000 resamples."""
    values = _trial_values(run)
    rng = np.random.default_rng(12345)
    idx = rng.integers(0, 12, size=(4000, 12))
    paired = {(r["method"], r["metric"]): r for r in _rows(run / "paired.csv")}
    assert {m for m, _ in paired} == {"qkf", "sage-husa"}
    for method in ("qkf", "sage-husa"):
        for j, col in enumerate(METRIC_COLUMNS):
            num = np.sqrt(np.mean(values[method][idx, j] ** 2, axis=1))
            den = np.sqrt(np.mean(values["kf"][idx, j] ** 2, axis=1))
            lo, hi = np.percentile(num / den, [2.5, 97.5])
            row = paired[(method, col)]
            ratio = np.sqrt(np.mean(values[method][:, j] ** 2)) / np.sqrt(
                np.mean(values["kf"][:, j] ** 2)
            )
            assert float(row["ratio"]) == pytest.approx(ratio, rel=1e-12)
            width = hi - lo
            assert float(row["lo"]) == pytest.approx(lo, abs=0.1 * width + 1e-12)
            assert float(row["hi"]) == pytest.approx(hi, abs=0.1 * width + 1e-12)


@pytest.mark.slow  # the module's 12-trial benchmark (fixture run)
def test_significance_marks_match_paired_csv(run: Path) -> None:
    text = (run / "summary.md").read_text()
    paired = _rows(run / "paired.csv")
    lines: dict[str, str] = {}
    for line in text.splitlines():  # the first table; the recovery table comes after it
        if line.startswith("|"):
            lines.setdefault(line.split("|")[1].strip(), line)
    for method in ("qkf", "sage-husa"):
        cells = [c.strip() for c in lines[method].split("|")[3:-2]]
        for cell, col in zip(cells, METRIC_COLUMNS, strict=True):
            row = next(r for r in paired if r["method"] == method and r["metric"] == col)
            # a mark needs both the pooled and the median interval on one side of 1, and
            # enough trials (paired.csv's verdict, docs/methods.md "Per-trial verdicts")
            verdict = paired_verdict(
                float(row["lo"]), float(row["hi"]), float(row["median_lo"]),
                float(row["median_hi"]), row["verdict"] != "unjudged",
            )  # fmt: skip
            assert verdict == row["verdict"], (method, col)
            expect = {"better": "↓", "worse": "↑"}.get(verdict, "")
            assert cell.endswith(expect) if expect else cell[-1].isdigit(), (method, col, cell)
    assert "Recovery after the calibration jump" in text


def test_bootstrap_rms_by_hand() -> None:
    ms = np.array([[1.0, 4.0], [9.0, 16.0], [25.0, 36.0]])
    counts = np.array([[3.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 2.0, 1.0]])
    out = bootstrap_rms(ms, counts)
    np.testing.assert_allclose(out[0], [1.0, 2.0])
    np.testing.assert_allclose(out[1], np.sqrt([35 / 3, 56 / 3]))
    np.testing.assert_allclose(out[2], np.sqrt([43 / 3, 68 / 3]))
    c = resample_counts(7, 500, seed=1)
    assert c.shape == (500, 7) and np.all(c.sum(axis=1) == 7)
    np.testing.assert_array_equal(c, resample_counts(7, 500, seed=1))


def test_a_lost_trial_makes_inf_only_of_the_resamples_that_draw_it() -> None:
    ms = np.array([[1.0], [np.inf], [9.0]])
    counts = np.array([[2.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 3.0, 0.0]])
    out = bootstrap_rms(ms, counts)[:, 0]
    assert out[0] == pytest.approx(np.sqrt(11 / 3)) and out[1] == out[2] == np.inf
    nan = bootstrap_rms(np.array([[1.0], [np.nan], [9.0]]), counts)[:, 0]  # NaN: lost as well
    assert nan[0] == pytest.approx(np.sqrt(11 / 3)) and nan[1] == nan[2] == np.inf


def test_percentiles_keep_infinities_where_numpy_gives_nan() -> None:
    x = np.array([3.0, 1.0, np.inf, 2.0])  # sorted 1, 2, 3, inf; virtual index 3q/100
    lo, mid, hi, top = percentiles(x, [2.5, 50.0, 97.5, 100.0])
    assert lo == pytest.approx(1.075) and mid == pytest.approx(2.5)
    assert hi == np.inf and top == np.inf  # numpy: NaN for both
    assert percentiles(np.array([1.0, 2.0, 3.0, np.inf]), [200 / 3])[0] == 3.0  # on a sample
    cols = np.random.default_rng(0).random((40, 3))
    cols[5, 1], cols[6, 2] = np.inf, np.nan
    got = percentiles(cols, [2.5, 90.0, 97.5])
    np.testing.assert_array_equal(got[:, 0], np.percentile(cols[:, 0], [2.5, 90.0, 97.5]))
    big = np.where(np.isinf(cols[:, 1]), 1e300, cols[:, 1])  # 90 % of 39 gaps stays below it
    np.testing.assert_allclose(got[:2, 1], np.percentile(big, [2.5, 90.0]))
    assert got[2, 1] == np.inf  # 97.5 % interpolates towards the inf
    assert np.isnan(got[:, 2]).all()


def test_a_method_that_loses_trials_is_judged_worse_not_inconclusive() -> None:
    """A method as good as the other except that it diverges on 3 of 40 trials: both the
    pooled and the per-trial intervals lie above 1 (before, 0 · inf spread NaN over every
    resample and the verdict read "inconclusive")."""
    rng = np.random.default_rng(4)
    base = 1.0 + 0.1 * rng.random(40)
    lossy = 1.05 * base
    lossy[[3, 17, 31]] = np.inf
    rows = versus_rows("f", {"lossy": lossy, "base": base}, ["lossy", "base"], 400, 0.95, 1)
    row, back = rows
    assert (row.method, row.other, row.ratio, row.hi) == ("lossy", "base", np.inf, np.inf)
    assert 1.0 < row.lo < np.inf and row.verdict == "worse"
    assert back.ratio == 0.0 and back.verdict == "better"


def test_interval_coverage() -> None:
    """The 95 % interval of an RMS covers the true RMS in about 95 % of experiments."""
    rng = np.random.default_rng(7)
    sigma, n, hits, experiments = 2.0, 60, 0, 300
    counts = resample_counts(n, 2000, seed=3)
    for _ in range(experiments):
        ms = (sigma * rng.standard_normal((n, 1))) ** 2
        lo, hi = percentile_interval(bootstrap_rms(ms, counts))
        hits += int(lo[0] <= sigma <= hi[0])
    # binomial sd at 95 % over 300 experiments is 1.3 %; the percentile bootstrap of an RMS
    # under-covers slightly at n = 60
    assert 0.88 <= hits / experiments <= 0.985


def test_recovery_time_by_hand() -> None:
    t = np.arange(10.0)
    rms = np.ones((10, 15))
    rms[5:8] = 3.0  # the jump at t = 5 lifts every group for three epochs
    rec = recovery_times(rms, t, jump_s=5.0, settled_s=1.0)
    assert rec == {g: 3.0 for g in rec}
    assert np.isnan(recovery_times(rms, t, jump_s=5.0, settled_s=6.0)["ma_urad"])
