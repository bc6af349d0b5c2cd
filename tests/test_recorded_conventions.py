"""Units and conventions of recorded data, checked before filtering
(qkf/transfer_alignment/recorded/conventions.py; docs/recorded_data.md, "Units and conventions").

A file written in deg/s, with times in ms, with a scalar-first or an inertial → body quaternion
is refused by name before any method runs (exit 2, nothing written); simulated files in the
documented convention pass, whatever the scenario.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.recorded import conventions
from qkf.transfer_alignment.recorded.columns import ADS_Q, ADS_RATE, GYRO
from qkf.transfer_alignment.recorded.grid import load_recorded
from qkf.transfer_alignment.recorded.reader import RecordedDataError, read_recorded
from qkf.transfer_alignment.recorded.writer import write_recorded
from qkf.transfer_alignment.scenario import simulate

SETS = ["scenario.duration_s=600"]


@pytest.fixture(scope="module")
def plain(tmp_path_factory: pytest.TempPathFactory) -> pd.DataFrame:
    """A simulated run of the paper scenario without truth columns, as a table."""
    cfg = load_config("paper", SETS)
    path = tmp_path_factory.mktemp("conv") / "plain.csv"
    write_recorded(path, simulate(cfg, 11, [0]), 0, truth=False)
    return pd.read_csv(path)


def _save(frame: pd.DataFrame, path: Path) -> Path:
    frame.to_csv(path, index=False, float_format="%.17g")
    return path


def _deg_s(frame: pd.DataFrame, columns: tuple[str, ...]) -> pd.DataFrame:
    out = frame.copy()
    for c in columns:
        out[c] = np.degrees(out[c])
    return out


def _scalar_first(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.copy()
    out[list(ADS_Q)] = frame[["ads_qw", "ads_qx", "ads_qy", "ads_qz"]].to_numpy()
    return out


def _conjugate(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.copy()
    for c in ADS_Q[:3]:
        out[c] = -out[c]
    return out


def _ms(frame: pd.DataFrame) -> pd.DataFrame:
    out = frame.copy()
    out["t_s"] = out["t_s"] * 1000.0
    return out


def _load(path: Path, *sets: str) -> None:
    load_recorded(load_config("paper", [*SETS, *sets]), [path])


@pytest.mark.parametrize(
    ("preset", "sets"),
    [
        ("paper", []),
        ("thermal_snap", []),
        ("paper", ["filter.matching=attitude"]),
        ("noise_mismatch", []),
        ("mixed_random", ["scenario.duration_s=3600"]),
        ("ads_mismatch_random", []),
        ("paper", ["scenario.dt_s=0.1", "scenario.duration_s=200"]),
    ],
)
def test_files_in_the_documented_convention_pass(tmp_path: Path, preset: str, sets: list) -> None:
    cfg = load_config(preset, [*SETS, *sets])
    for seed in (1, 2):
        path = tmp_path / f"{seed}.csv"
        write_recorded(path, simulate(cfg, seed, [0]), 0, truth=seed == 1)
        load_recorded(cfg, [path])  # raises if refused


@pytest.mark.parametrize(
    ("change", "hint"),
    [
        (lambda f: _deg_s(f, (*GYRO, *ADS_RATE)), "rates in deg/s?"),
        (lambda f: _deg_s(f, GYRO), "rates in deg/s?"),
        (_scalar_first, "scalar-first quaternion?"),
        (_conjugate, "inertial → body quaternion?"),
        (_ms, "t_s in milliseconds?"),
        (lambda f: _deg_s(_scalar_first(f), GYRO), "scalar-first quaternion? (ads_qx"),
    ],
    ids=["deg_s", "gyro_deg_s", "scalar_first", "conjugate", "ms", "scalar_first_deg_s"],
)
def test_a_wrong_convention_is_refused_by_name(
    tmp_path: Path, plain: pd.DataFrame, change, hint: str
) -> None:  # type: ignore[no-untyped-def]
    path = _save(change(plain), tmp_path / "bad.csv")
    with pytest.raises(RecordedDataError, match="Units and conventions") as err:
        _load(path)
    assert hint in str(err.value)
    assert str(path) in str(err.value)


def test_the_ads_rate_alone_in_deg_s_is_named(tmp_path: Path, plain: pd.DataFrame) -> None:
    path = _save(_deg_s(plain, ADS_RATE), tmp_path / "ads.csv")
    with pytest.raises(RecordedDataError) as err:
        _load(path)
    text = str(err.value)
    assert "ads_wx_rad_s" in text and "rates in deg/s?" in text
    assert "gyro_wx_rad_s" not in text  # the gyro itself agrees


def test_rates_that_fit_no_convention_are_refused(tmp_path: Path, plain: pd.DataFrame) -> None:
    """Gyro axes swapped (x ↔ y): no unit or quaternion convention explains it."""
    bad = plain.copy()
    bad[[GYRO[0], GYRO[1]]] = plain[[GYRO[1], GYRO[0]]].to_numpy()
    path = _save(bad, tmp_path / "swapped.csv")
    with pytest.raises(RecordedDataError, match="no unit or quaternion convention"):
        _load(path)
    # the check can be switched off for a rig whose frames differ on purpose
    _load(path, "recorded.check_conventions=false")


def test_a_run_at_rest_cannot_be_judged_and_passes(tmp_path: Path, plain: pd.DataFrame) -> None:
    """No rotation above the noise: no window says anything about a scale."""
    rest = plain.copy()
    rest[list(ADS_Q)] = [0.0, 0.0, 0.0, 1.0]
    for c in (*GYRO, *ADS_RATE):
        rest[c] = 1e-7
    path = _save(rest, tmp_path / "rest.csv")
    _load(path)
    # the same file in deg/s still says nothing: the gyro reads bias only
    _load(_save(_deg_s(rest, GYRO), tmp_path / "rest_deg.csv"))


def test_window_means_against_a_direct_sum(monkeypatch: pytest.MonkeyPatch) -> None:
    """The time-weighted window means, across chunk boundaries and with absent rows, against
    a loop over the rows."""
    rng = np.random.default_rng(4)
    n = 200
    t = np.cumsum(rng.uniform(0.5, 1.5, n))
    values = rng.normal(size=(n, 3))
    values[[5, 6, 40, 41, 42, 150]] = np.nan
    start = np.array([0, 3, 38, 40, 100, 149])
    end = np.array([10, 12, 45, 43, 130, 199])
    duration = t[end] - t[start]
    monkeypatch.setattr(conventions, "_CHUNK_ROWS", 7)
    got = conventions._window_means(values, np.diff(t), start, end, duration)
    for k, (a, b) in enumerate(zip(start, end, strict=True)):
        rows = [r for r in range(a, b) if np.isfinite(values[r]).all()]
        w = np.array([t[r + 1] - t[r] for r in rows])
        if w.sum() <= 0.5 * duration[k]:
            assert np.isnan(got[k]).all()
        else:
            expect = (values[rows] * w[:, None]).sum(axis=0) / w.sum()
            np.testing.assert_allclose(got[k], expect, rtol=1e-12)
    assert np.isfinite(got[2]).all()  # rows 38–44 with 40–42 absent: over half covered
    assert np.isnan(got[3]).all()  # rows 40–42: all absent


def test_the_cli_refuses_the_two_files_of_the_report(tmp_path: Path, plain: pd.DataFrame) -> None:
    """The two diverging files of the issue: rates written in deg/s, a scalar-first quaternion.
    Exit 2, the cause named, nothing written."""
    runner = CliRunner()
    for name, frame, hint in (
        ("rates_in_deg_per_s.csv", _deg_s(plain, (*GYRO, *ADS_RATE)), "rates in deg/s?"),
        ("scalar_first.csv", _scalar_first(plain), "scalar-first quaternion?"),
    ):
        path = _save(frame, tmp_path / name)
        out = tmp_path / f"out_{name}"
        res = runner.invoke(
            app,
            ["bench", "paper", "--set", "scenario.duration_s=600", "--data", str(path),
             "--methods", "kf", "--out", str(out), "--quiet"],
        )  # fmt: skip
        assert res.exit_code == 2, res.output
        assert hint in res.output and name in res.output
        assert not out.exists()


def test_reading_does_not_depend_on_the_check(tmp_path: Path, plain: pd.DataFrame) -> None:
    """The check reads the run; it never changes it."""
    path = _save(plain, tmp_path / "p.csv")
    run = read_recorded(path)
    before = run.gyro.copy(), run.ads_q.copy()
    conventions.check_conventions(run, 3 * 4.84813681109536e-6, 9.7e-6)
    assert np.array_equal(before[0], run.gyro) and np.array_equal(before[1], run.ads_q)
