"""No silent divergence (qkf/transfer_alignment/divergence.py; docs/recorded_data.md,
"Divergence"): a run whose estimate turns non-finite, or whose NIS stays implausible, is found
at its first epoch, named in summary.md and on the terminal, and ``qkf bench`` exits 3."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.divergence import (
    EXIT_DIVERGED,
    NIS_IMPLAUSIBLE,
    NIS_RUN,
    find_divergences,
)
from qkf.transfer_alignment.methods import METHODS
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.recorded.columns import ADS_RATE, GYRO
from qkf.transfer_alignment.recorded.writer import write_recorded
from qkf.transfer_alignment.scenario import simulate

runner = CliRunner()
B, N = 3, 200


def _output(**kw) -> MethodOutput:  # type: ignore[no-untyped-def]
    est = np.zeros((B, N, 16))
    est[..., 3] = 1.0
    nis = np.full((B, N, 2), 3.0)
    nis[:, 1::2] = np.nan  # updates every other epoch
    base = {"est": est, "diverged": np.zeros(B, dtype=bool), "nis": nis,
            "var": np.full((B, N, 15), 1e-10)}  # fmt: skip
    base.update(kw)
    return MethodOutput(**base)


def test_a_consistent_run_has_no_divergence() -> None:
    t = np.arange(N, dtype=float)
    assert find_divergences("kf", _output(), t, np.arange(B)) == []


def test_the_first_non_finite_epoch_is_named() -> None:
    out = _output()
    out.est[1, 57:, 5] = np.nan
    out.est[2, 120:, 0] = np.inf
    t = 0.5 * np.arange(N)
    divs = find_divergences("kf", out, t, np.array([10, 11, 12]))
    assert [(d.trial, d.epoch, d.t_s) for d in divs] == [(11, 57, 28.5), (12, 120, 60.0)]
    assert "not finite" in divs[0].cause
    assert "trial 11 (run.csv), epoch 57 (t = 28.5 s)" in divs[0].describe("run.csv")


def test_a_sustained_implausible_nis_is_a_divergence_and_a_short_one_is_not() -> None:
    out = _output()
    updates = np.arange(0, N, 2)
    # trial 0: NIS_RUN − 1 implausible updates in a row, then a normal one: no divergence
    out.nis[0, updates[20 : 20 + NIS_RUN - 1], 0] = 3 * NIS_IMPLAUSIBLE * 10
    # trial 1: NIS_RUN in a row from update 30 (the epochs between updates have no NIS)
    out.nis[1, updates[30 : 30 + NIS_RUN], 1] = 3 * NIS_IMPLAUSIBLE * 1.01
    # trial 2: a noise level wrong by 10 in σ (NIS/3 ≈ 100) throughout: not a divergence
    out.nis[2, updates, 0] = 300.0
    divs = find_divergences("glr", out, np.arange(N, dtype=float), np.arange(B))
    assert [(d.trial, d.epoch) for d in divs] == [(1, int(updates[30]))]
    assert "rate NIS/3" in divs[0].cause


def test_a_negative_variance_and_a_method_flag() -> None:
    out = _output(diverged=np.array([False, False, True]))
    out.var[0, 33, 7] = -1e-12
    divs = find_divergences("m", out, np.arange(N, dtype=float), np.arange(B))
    assert [(d.trial, d.epoch) for d in divs] == [(0, 33), (2, -1)]
    assert np.isnan(divs[1].t_s) and "flagged" in divs[1].cause
    assert "epoch" not in divs[1].describe()


def test_the_earliest_cause_wins() -> None:
    out = _output()
    out.est[0, 90:, 4] = np.nan
    out.var[0, 40, 3] = np.inf
    divs = find_divergences("m", out, np.arange(N, dtype=float), np.arange(B))
    assert [(d.epoch, "variance" in d.cause) for d in divs] == [(40, True)]


def kf_that_diverges(cfg, data):  # type: ignore[no-untyped-def]
    """A user method (``tests.test_divergence:kf_that_diverges``): kf, with trial id 1 turning
    NaN at epoch 50."""
    out = METHODS["kf"](cfg, data)
    hit = np.flatnonzero(np.asarray(data.trial_ids) == 1)
    out.est[hit, 50:] = np.nan
    return out


def test_bench_exits_3_and_names_the_divergence(tmp_path: Path) -> None:
    folder = tmp_path / "out"
    res = runner.invoke(
        app,
        ["bench", "paper", "--set", "scenario.duration_s=200", "--trials", "3", "--quiet",
         "--methods", "kf,tests.test_divergence:kf_that_diverges", "--out", str(folder)],
    )  # fmt: skip
    assert res.exit_code == EXIT_DIVERGED, res.output
    line = "method tests.test_divergence:kf_that_diverges, trial 1, epoch 50 (t = 50 s)"
    assert line in res.output
    summary = (folder / "summary.md").read_text()
    assert "## Diverged" in summary and line in summary
    assert "kf, trial" not in summary.split("## Diverged")[1].split("\n\n")[1].replace(
        "kf_that_diverges", ""
    )  # plain kf did not diverge


def test_a_diverging_recorded_file_exits_3_naming_the_file(tmp_path: Path) -> None:
    """The rates in deg/s with the convention check switched off: the filter runs and
    diverges; exit 3, the file and epoch named, and no summary says the data fit."""
    cfg = load_config("paper", ["scenario.duration_s=600"])
    path = tmp_path / "deg.csv"
    write_recorded(path, simulate(cfg, 3, [0]), 0, truth=False)
    frame = pd.read_csv(path)
    for c in (*GYRO, *ADS_RATE):
        frame[c] = np.degrees(frame[c])
    frame.to_csv(path, index=False, float_format="%.17g")
    folder = tmp_path / "out"
    res = runner.invoke(
        app,
        ["bench", "paper", "--set", "scenario.duration_s=600", "--set",
         "recorded.check_conventions=false", "--data", str(path), "--methods", "kf", "--quiet",
         "--out", str(folder)],
    )  # fmt: skip
    assert res.exit_code == EXIT_DIVERGED, res.output
    assert f"method kf, trial 0 ({path})" in res.output
    summary = (folder / "summary.md").read_text()
    assert "## Diverged" in summary and str(path) in summary
    assert "fit its noise model" not in summary


@pytest.mark.parametrize("duration", [2.0, 420.0])
def test_a_file_too_short_to_judge_is_refused(tmp_path: Path, duration: float) -> None:
    """A 2-row file, and one whose settled window holds 20 updates: exit 2, the minimum named,
    nothing written; a shorter settled window makes the second one judgeable."""
    cfg = load_config("paper", [f"scenario.duration_s={duration}"])
    path = tmp_path / "short.csv"
    write_recorded(path, simulate(cfg, 3, [0]), 0, truth=False)
    folder = tmp_path / "out"
    args = ["bench", "paper", "--data", str(path), "--methods", "kf", "--quiet",
            "--out", str(folder)]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 2, res.output
    assert "too short to judge" in res.output and "at least 40" in res.output
    assert not folder.exists()
    if duration > 100:
        res = runner.invoke(app, [*args, "--set", "run.settled_s=100"])
        assert res.exit_code == 0, res.output
        assert "(t ≥ 100 s)" in (folder / "summary.md").read_text()


def test_a_sweep_with_a_diverging_case_exits_3(tmp_path: Path) -> None:
    """Each case's summary.md names its divergence; the sweep's command exits 3 after the
    sweep, naming the cases."""
    folder = tmp_path / "sweep"
    res = runner.invoke(
        app,
        ["bench", "noise_mismatch", "--set", "scenario.duration_s=100", "--set",
         "sweep.values=[1.0,3.0]", "--trials", "2", "--quiet", "--methods",
         "tests.test_divergence:kf_that_diverges", "--out", str(folder)],
    )  # fmt: skip
    assert res.exit_code == EXIT_DIVERGED, res.output
    cases = sorted(p for p in folder.iterdir() if p.is_dir())
    assert len(cases) == 2
    for case in cases:
        assert "## Diverged" in (case / "summary.md").read_text()
        assert f"diverged: {case / 'summary.md'}" in res.output.replace("\n", "")
