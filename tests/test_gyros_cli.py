"""``qkf gyros``: the output contracts of features, run and bench; recorded data give the same
result as the simulation they came from; bad config and data files exit 2 with file and
field/line/column named and nothing written."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import simulate_run
from qkf.redundant_gyros.report import CALIBRATION_COLUMNS, FDI_COLUMNS

runner = CliRunner()
SHORT = ["--set", "scenario.duration_s=90"]


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


def test_help_lists_the_commands() -> None:
    res = runner.invoke(app, ["gyros", "--help"])
    assert res.exit_code == 0
    for cmd in ("features", "run", "bench"):
        assert cmd in res.output


def test_features_table(tmp_path: Path) -> None:
    out = tmp_path / "f.csv"
    res = runner.invoke(app, ["gyros", "features", "five_gyros", "--out", str(out)])
    assert res.exit_code == 0, res.output
    rows = _rows(out)
    assert list(rows[0]) == ["gyro", "feature_nominal", "feature_with_errors"]
    unit = build_unit(load_config("five_gyros"))
    assert [r["gyro"] for r in rows] == list(unit.ids)
    np.testing.assert_allclose([float(r["feature_nominal"]) for r in rows], unit.signature)
    assert "X and Y are hard to tell apart" in res.output


@pytest.mark.figures
def test_run_writes_the_contract_files(tmp_path: Path) -> None:
    out = tmp_path / "run"
    res = runner.invoke(app, ["gyros", "run", "five_gyros_s_bias", "--out", str(out), *SHORT])
    assert res.exit_code == 0, res.output
    for name in ("fdi.csv", "calibration.csv", "summary.md", "run.json"):
        assert (out / name).is_file()
    for name in ("feature.png", "glt.png", "calibration.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    fdi = _rows(out / "fdi.csv")
    assert tuple(fdi[0]) == FDI_COLUMNS
    assert len(fdi) == 900
    late = fdi[700:]
    assert {r["isolated_threecross"] for r in late} == {"S"}
    assert {r["isolated_glt"] for r in late} == {"S"}
    assert {r["model"] for r in late} == {"XYZ"}
    assert {r["model"] for r in fdi[:500]} == {"fusion"}
    cal = _rows(out / "calibration.csv")
    assert tuple(cal[0]) == CALIBRATION_COLUMNS
    assert {r["gyro"] for r in cal} == {"S"}
    assert float(cal[-1]["bias_degs"]) == pytest.approx(0.1, abs=5 * float(cal[-1]["sd_bias_degs"]))
    summary = (out / "summary.md").read_text()
    assert "Gyro S" in summary and "Converged" in summary


def test_recorded_data_give_the_simulations_result(tmp_path: Path) -> None:
    cfg = load_config("five_gyros_y_misalignment", ["scenario.duration_s=90"])
    data = simulate_run(cfg, seed=3)
    path = tmp_path / "data.csv"
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", *cfg.unit.ids(), "temperature"])
        for k, t in enumerate(data.t):
            w.writerow([repr(float(t)), *(repr(float(v)) for v in data.meas[0, k]), 20.0])
    a, b = tmp_path / "sim", tmp_path / "rec"
    sets = ["five_gyros_y_misalignment", *SHORT]
    assert (
        runner.invoke(app, ["gyros", "run", *sets, "--seed", "3", "--out", str(a)]).exit_code == 0
    )
    res = runner.invoke(app, ["gyros", "run", *sets, "--data", str(path), "--out", str(b)])
    assert res.exit_code == 0, res.output
    assert (a / "fdi.csv").read_text() == (b / "fdi.csv").read_text()
    assert (a / "calibration.csv").read_text() == (b / "calibration.csv").read_text()
    assert "recorded" in (b / "summary.md").read_text()
    assert "truth" not in (b / "summary.md").read_text()


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


BAD_DATA = {
    "missing column": ("t_s,X,Y,Z,S\n0,1,1,1,1\n0.1,1,1,1,1\n", "line 1: missing column 'T'"),
    "time not increasing": (
        "t_s,X,Y,Z,S,T\n0,1,1,1,1,1\n0.1,1,1,1,1,1\n0.1,1,1,1,1,1\n",
        "line 4: column t_s: time does not increase",
    ),
    "not finite": (
        "t_s,X,Y,Z,S,T\n0,1,1,1,1,1\n0.1,1,nan,1,1,1\n",
        "line 3: column Y: not a finite number ('nan')",
    ),
    "not a number": ("t_s,X,Y,Z,S,T\n0,1,1,1,1,1\n0.1,1,1,1,x,1\n", "line 3: column S"),
    "empty cell": ("t_s,X,Y,Z,S,T\n0,1,1,1,1,1\n0.1,1,1,1,1\n", "line 3: column T: empty"),
}


@pytest.mark.parametrize("case", list(BAD_DATA))
def test_bad_data_exit_2_naming_line_and_column(case: str, tmp_path: Path) -> None:
    text, message = BAD_DATA[case]
    data = _write(tmp_path / "d.csv", text)
    out = tmp_path / "out"
    res = runner.invoke(app, ["gyros", "run", "five_gyros", "--data", str(data), "--out", str(out)])
    assert res.exit_code == 2
    flat = " ".join(res.output.split())
    assert str(data) in flat and message in flat
    assert not out.exists() and list(tmp_path.iterdir()) == [data]


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("scenario:\n  duraton_s: 10\n", "scenario.duraton_s: unknown key"),
        ("fdi:\n  false_alarm_probability: 0\n", "fdi.false_alarm_probability"),
        (
            "scenario:\n  faults:\n    - {gyro: W, t_s: 1, kind: bias_step, size: 1}\n",
            "scenario.faults.0.gyro: unknown gyro 'W'",
        ),
        ("unit:\n  gyros:\n    - {id: X, w: [1, 0, 0], u: [0, 1, 0]}\n", "unit.gyros"),
    ],
)
@pytest.mark.parametrize("command", ["features", "run", "bench"])
def test_bad_config_exit_2_naming_file_and_field(
    text: str, field: str, command: str, tmp_path: Path
) -> None:
    cfg = _write(tmp_path / "bad.yaml", text)
    out = tmp_path / ("out.csv" if command == "features" else "out")
    res = runner.invoke(app, ["gyros", command, str(cfg), "--out", str(out)])
    assert res.exit_code == 2, res.output
    flat = " ".join(res.output.split())
    assert str(cfg) in flat and field in flat
    assert list(tmp_path.iterdir()) == [cfg]


def test_unknown_preset_lists_the_gyro_presets(tmp_path: Path) -> None:
    res = runner.invoke(app, ["gyros", "features", "five_gyro", "--out", str(tmp_path / "f")])
    assert res.exit_code == 2
    assert "five_gyros_s_bias" in res.output


@pytest.mark.figures
def test_bench_writes_its_tables(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    sets = [
        "--set",
        "bench.kinds=[bias_step, stuck]",
        "--set",
        "bench.sizes_sigma=[8]",
        "--set",
        "bench.ukf_trials=2",
        "--set",
        "scenario.duration_s=75",
    ]
    res = runner.invoke(
        app,
        [
            "gyros",
            "bench",
            "five_gyros_s_bias",
            "--trials",
            "10",
            "--quiet",
            *sets,
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    rows = _rows(out / "bench.csv")
    assert {(r["method"], r["kind"]) for r in rows} == {
        (m, k) for m in ("threecross", "glt", "glt_window") for k in ("bias_step", "stuck")
    }
    for r in rows:
        assert int(r["trials"]) == 10
        for metric in ("false_alarm_rate", "missed_detection", "correct_isolation"):
            v, lo, hi = (float(r[metric + s]) for s in ("", "_lo", "_hi"))
            assert 0.0 <= lo <= v <= hi <= 1.0
    ukf = _rows(out / "ukf.csv")
    assert len(ukf) == 150 and float(ukf[-1]["nees"]) > 0
    assert (out / "bench.png").is_file() and (out / "ukf.png").is_file()
    assert "glt_window" in (out / "summary.md").read_text()


def test_trials_option_is_checked(tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["gyros", "bench", "five_gyros", "--trials", "0", "--out", str(tmp_path / "b")]
    )
    assert res.exit_code == 2 and "--trials" in res.output


def test_run_summary_says_when_a_detector_fires_before_the_fault(tmp_path: Path) -> None:
    """The detectors' table counts each detector's alarms before the injected fault and its
    delay after it, as fdi.csv shows them, and remarks on a detector that fired early."""
    out = tmp_path / "run"
    res = runner.invoke(
        app, ["gyros", "run", "five_gyros_y_misalignment", "--out", str(out), *SHORT]
    )
    assert res.exit_code == 0, res.output
    t_fault = load_config("five_gyros_y_misalignment").scenario.faults[0].t_s
    fdi = _rows(out / "fdi.csv")
    summary = (out / "summary.md").read_text()
    for name, column in (("three-cross", "isolated_threecross"), ("GLT", "isolated_glt")):
        flagged = [float(r["t_s"]) for r in fdi if r[column]]
        before = [t for t in flagged if t < t_fault]
        after = [t for t in flagged if t >= t_fault]
        row = next(line for line in summary.splitlines() if line.startswith(f"| {name}"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert int(cells[4]) == len(before)
        assert float(cells[5]) == pytest.approx(after[0] - t_fault, abs=1e-6)
        assert (f"- {name}" in summary and "before the fault" in summary) == bool(before)
    assert "false alarms" in summary  # GLT fires at 34.1 s on this seed, the fault is at 60 s
