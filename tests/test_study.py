"""`qkf study`: cases run and plotted together; the CRLB study shows what longer rotations buy."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import ConfigError
from qkf.transfer_alignment.study import load_study, study_cases
from tests.conftest import CONFIGS

runner = CliRunner()
# claims studies (kind: claims) have their own loader: tests/test_claims.py
STUDIES = sorted(
    p for p in (CONFIGS / "studies").glob("*.yaml") if "kind: claims" not in p.read_text()
)


@pytest.mark.parametrize("path", STUDIES, ids=lambda p: p.stem)
def test_study_files_load(path: Path) -> None:
    study, configs = load_study(path)
    assert len(configs) == len(study_cases(study)) >= 2


@pytest.mark.figures
def test_rotation_duration_study(tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        [
            "study",
            str(CONFIGS / "studies/rotation_duration.yaml"),
            "--out",
            str(tmp_path),
            "--quiet",
        ],
    )
    assert result.exit_code == 0, result.output
    with (tmp_path / "study.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["case"] for r in rows] == [f"{d} s per axis" for d in (100, 200, 400, 600)]
    final_ma = [float(r["ma_urad_final"]) for r in rows]
    # longer rotations about each axis: a tighter bound on the misalignments at the end
    assert final_ma == sorted(final_ma, reverse=True) and final_ma[-1] < 0.6 * final_ma[0]
    assert (tmp_path / "study.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "600_s_per_axis" / "crlb.csv").exists()


def test_bench_study_writes_each_case(tmp_path: Path) -> None:
    study = tmp_path / "s.yaml"
    study.write_text(
        f"name: t\nkind: bench\nbase: {CONFIGS / 'paper.yaml'}\nmethods: [kf, qkf]\ntrials: 2\n"
        "metric: att_arcsec_avg\ncases:\n"
        "  - {label: a, set: [filter.matching=attitude, scenario.duration_s=300]}\n"
        "  - {label: b, set: [scenario.duration_s=300]}\n"
    )
    result = runner.invoke(app, ["study", str(study), "--out", str(tmp_path / "o"), "--quiet"])
    assert result.exit_code == 0, result.output
    with (tmp_path / "o/study.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["case"], r["method"]) for r in rows] == [
        ("a", "kf"),
        ("a", "qkf"),
        ("b", "kf"),
        ("b", "qkf"),
    ]
    assert (tmp_path / "o/a/summary.csv").exists() and (tmp_path / "o/b/kappa.csv").exists()


def test_bad_study_is_refused(tmp_path: Path) -> None:
    study = tmp_path / "s.yaml"
    study.write_text(
        f"name: t\nbase: {CONFIGS / 'paper.yaml'}\nmetric: nope\ncases: [{{label: a}}]\n"
    )
    with pytest.raises(ConfigError, match="metric"):
        load_study(study)
    result = runner.invoke(app, ["study", str(study), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and not (tmp_path / "o").exists()
