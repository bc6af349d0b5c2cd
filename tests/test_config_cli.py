"""Configs: presets load, bad input is refused clearly (exit 2, file and field named, nothing
written), overrides work; the CLI writes the SPEC §8 formats."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import ConfigError, load_config
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.states import STATE_COLUMNS
from tests.conftest import CONFIGS

runner = CliRunner()
PRESETS = ["paper", "attitude_only", "thermal_drift", "thermal_snap", "noise_mismatch"]


@pytest.mark.parametrize("name", PRESETS)
def test_every_preset_loads(name: str) -> None:
    cfg = load_config(CONFIGS / f"{name}.yaml")
    assert cfg.scenario.duration_s == 3600
    assert cfg.filter.qp0 == 1e-14


def test_noise_mismatch_sweeps_the_true_attitude_noise() -> None:
    cfg = load_config(CONFIGS / "noise_mismatch.yaml")
    assert cfg.sweep is not None
    assert cfg.sweep.key == "scenario.ads.attitude_sigma_arcsec"
    assert cfg.sweep.values == [1, 2, 3, 5, 10]
    assert cfg.filter.attitude_sigma_arcsec == 3.0


BAD = {
    "unknown key": ("scenario:\n  duraton_s: 100\n", "scenario.duraton_s", "unknown key"),
    "negative duration": (
        "scenario:\n  maneuvers:\n    - {start_s: 0, duration_s: -5, axis: x, rate_deg_s: 1}\n",
        "scenario.maneuvers.0.duration_s",
        "greater than 0",
    ),
    "non-positive sigma": (
        "scenario:\n  ads: {attitude_sigma_arcsec: 0}\n",
        "scenario.ads.attitude_sigma_arcsec",
        "greater than 0",
    ),
    "bad axis": (
        "scenario:\n  maneuvers:\n    - {start_s: 0, duration_s: 5, axis: w, rate_deg_s: 1}\n",
        "scenario.maneuvers.0.axis",
        "'x', 'y' or 'z'",
    ),
}


@pytest.mark.parametrize("kind", list(BAD))
@pytest.mark.parametrize("command", ["crlb", "bench"])
def test_bad_config_is_refused_and_nothing_written(kind: str, command: str, tmp_path: Path) -> None:
    text, field, phrase = BAD[kind]
    cfg_file = tmp_path / "bad.yaml"
    cfg_file.write_text(text)
    out = tmp_path / ("out.csv" if command == "crlb" else "outdir")
    result = runner.invoke(app, [command, str(cfg_file), "--out", str(out)])
    assert result.exit_code == 2, result.output
    msg = result.stderr
    assert str(cfg_file) in msg and field in msg and phrase in msg, msg
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [cfg_file]


def test_set_overrides_and_their_errors(tmp_path: Path) -> None:
    cfg = load_config(
        CONFIGS / "paper.yaml",
        ["scenario.randomize_truth=true", "filter.qp0=1e-20", "scenario.maneuvers.1.rate_deg_s=2"],
    )
    assert cfg.scenario.randomize_truth is True
    assert cfg.filter.qp0 == 1e-20
    assert cfg.scenario.maneuvers[1].rate_deg_s == 2.0
    with pytest.raises(ConfigError, match=r"filter\.qq0: unknown key"):
        load_config(CONFIGS / "paper.yaml", ["filter.qq0=1"])
    with pytest.raises(ConfigError, match=r"expected dotted\.key=value"):
        load_config(CONFIGS / "paper.yaml", ["filter.qp0"])
    with pytest.raises(ConfigError, match="not an index"):
        load_config(CONFIGS / "paper.yaml", ["scenario.maneuvers.7.axis=x"])
    result = runner.invoke(
        app,
        [
            "crlb",
            str(CONFIGS / "paper.yaml"),
            "--out",
            str(tmp_path / "c.csv"),
            "--set",
            "filter.qp0=-1",
        ],
    )
    assert result.exit_code == 2
    assert "filter.qp0" in result.stderr
    assert not (tmp_path / "c.csv").exists()


def test_missing_file_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "x.yaml"
    bad.write_text("scenario: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_crlb_command_writes_the_spec_format(tmp_path: Path) -> None:
    out = tmp_path / "crlb.csv"
    result = runner.invoke(
        app,
        [
            "crlb",
            str(CONFIGS / "paper.yaml"),
            "--out",
            str(out),
            "--set",
            "scenario.duration_s=500",
        ],
    )
    assert result.exit_code == 0, result.output
    with out.open() as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == ("t_s", *STATE_COLUMNS)
    assert len(rows) == 501
    values = np.array(rows[1:], dtype=float)
    np.testing.assert_array_equal(values[:, 0], np.arange(500.0))
    cfg = load_config(CONFIGS / "paper.yaml", ["scenario.duration_s=500"])
    ref = crlb(cfg).bound
    # display units: arcsec, deg/h, ppm, µrad
    np.testing.assert_allclose(values[-1, 1], ref[-1, 0] / (np.pi / 180 / 3600), rtol=1e-12)
    np.testing.assert_allclose(values[-1, 4], ref[-1, 3] / (np.pi / 180 / 3600), rtol=1e-12)
    np.testing.assert_allclose(values[-1, 7], ref[-1, 6] / 1e-6, rtol=1e-12)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "temp file left behind"
