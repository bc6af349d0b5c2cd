"""Hints for files written by other tools (docs/recorded_data.md, "Bad input"): another
separator or decimal commas are named; extra columns are refused unless named to be ignored,
and an ignored column changes nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.recorded.columns import ADS_Q, ADS_RATE, GYRO
from qkf.transfer_alignment.recorded.grid import load_recorded
from qkf.transfer_alignment.recorded.reader import ReadLimits, RecordedDataError, read_recorded
from qkf.transfer_alignment.recorded.writer import write_recorded
from qkf.transfer_alignment.scenario import simulate

runner = CliRunner()


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("hints") / "good.csv"
    cfg = load_config("paper", ["scenario.duration_s=60"])
    write_recorded(path, simulate(cfg, 5, [0]), 0, truth=False)
    return path


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def test_semicolons_and_tabs_are_named(tmp_path: Path, good: Path) -> None:
    for sep, word in ((";", "';'"), ("\t", "tabs")):
        path = tmp_path / "other.csv"
        path.write_text("\n".join(line.replace(",", sep) for line in _lines(good)) + "\n")
        with pytest.raises(RecordedDataError, match=f"separated by {word}"):
            read_recorded(path)


def test_a_decimal_comma_locale_export_is_named(tmp_path: Path, good: Path) -> None:
    """';' between cells and ',' in numbers: what a spreadsheet writes in such a locale."""
    path = tmp_path / "locale.csv"
    rows = [line.replace(",", ";").replace(".", ",") for line in _lines(good)]
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(RecordedDataError, match="decimal-comma locale"):
        read_recorded(path)


def test_decimal_commas_in_a_comma_separated_file_are_named(tmp_path: Path, good: Path) -> None:
    lines = _lines(good)
    path = tmp_path / "comma.csv"
    path.write_text("\n".join([lines[0], *(r.replace(".", ",") for r in lines[1:])]) + "\n")
    with pytest.raises(RecordedDataError, match="decimal commas") as err:
        read_recorded(path)
    assert "row 1 (line 2)" in str(err.value)


def test_extra_columns_are_refused_with_the_option_named(tmp_path: Path, good: Path) -> None:
    lines = _lines(good)
    path = tmp_path / "extra.csv"
    path.write_text(
        "\n".join([lines[0] + ",temp_c,mode", *(r + f",{i}.5,a" for i, r in enumerate(lines[1:]))])
        + "\n"
    )
    with pytest.raises(RecordedDataError, match="--ignore-column") as err:
        read_recorded(path)
    assert "'temp_c'" in str(err.value) and "'mode'" in str(err.value)
    plain = read_recorded(good)
    run = read_recorded(path, ReadLimits(ignore_columns=frozenset({"temp_c", "mode"})))
    for name in ("t", "ads_q", "ads_rate", "gyro"):
        assert np.array_equal(getattr(run, name), getattr(plain, name), equal_nan=True)
    # the same for Parquet
    pq_path = tmp_path / "extra.parquet"
    arrays = {"t_s": plain.t, "temp_c": np.ones(plain.n_rows)}
    for cols, values in ((ADS_Q, plain.ads_q), (ADS_RATE, plain.ads_rate), (GYRO, plain.gyro)):
        for j, c in enumerate(cols):
            arrays[c] = values[:, j]
    pq.write_table(pa.table(arrays), pq_path)
    with pytest.raises(RecordedDataError, match="'temp_c'"):
        read_recorded(pq_path)
    run = read_recorded(pq_path, ReadLimits(ignore_columns=frozenset({"temp_c"})))
    assert np.array_equal(run.gyro, plain.gyro)


def test_a_column_qkf_reads_cannot_be_ignored(good: Path) -> None:
    with pytest.raises(RecordedDataError, match="cannot be ignored"):
        read_recorded(good, ReadLimits(ignore_columns=frozenset({"gyro_wx_rad_s"})))


def test_the_cli_option_and_the_config_field(tmp_path: Path, good: Path) -> None:
    lines = _lines(good)
    path = tmp_path / "extra.csv"
    path.write_text("\n".join([lines[0] + ",note", *(r + ",x" for r in lines[1:])]) + "\n")
    base = ["bench", "paper", "--data", str(path), "--methods", "kf", "--quiet",
            "--set", "run.settled_s=10"]  # fmt: skip
    res = runner.invoke(app, [*base, "--out", str(tmp_path / "a")])
    assert res.exit_code == 2 and "--ignore-column" in res.output
    assert not (tmp_path / "a").exists()
    res = runner.invoke(app, [*base, "--ignore-column", "note", "--out", str(tmp_path / "b")])
    assert res.exit_code == 0, res.output
    cfg = load_config("paper", ["recorded.ignore_columns=[note]"])
    assert load_recorded(cfg, [path]).data.n_epochs == load_recorded(cfg, [good]).data.n_epochs
    res = runner.invoke(
        app, ["bench", "paper", "--ignore-column", "note", "--out", str(tmp_path / "c")]
    )
    assert res.exit_code == 2 and "--ignore-column is for the files of --data" in res.output
