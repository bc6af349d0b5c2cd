"""The recorded-run file format: exact round trip, and every bad input refused with the file,
row and column named, exit 2 and nothing written (docs/recorded_data.md, "Bad input")."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.recorded.columns import ALL_COLUMNS, REQUIRED_COLUMNS
from qkf.transfer_alignment.recorded.reader import (
    ReadLimits,
    RecordedDataError,
    data_files,
    read_recorded,
)
from qkf.transfer_alignment.recorded.writer import write_recorded
from qkf.transfer_alignment.scenario import simulate


@pytest.fixture(scope="module")
def sim():  # type: ignore[no-untyped-def]
    cfg = load_config("paper", ["scenario.duration_s=60"])
    return simulate(cfg, 3, [0])


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
@pytest.mark.parametrize("truth", [True, False])
def test_round_trip_is_exact(tmp_path: Path, sim, suffix: str, truth: bool) -> None:  # type: ignore[no-untyped-def]
    from dataclasses import replace

    meas = np.ones(sim.n_epochs, dtype=bool)
    meas[10:14] = False  # epochs without an ADS measurement: empty cells
    data = replace(sim, has_meas=meas)
    path = tmp_path / f"r{suffix}"
    write_recorded(path, data, truth=truth)
    run = read_recorded(path)
    assert np.array_equal(run.t, data.t)
    assert np.array_equal(run.gyro, data.gyro[0])
    assert np.array_equal(run.has_attitude, meas) and np.array_equal(run.has_rate, meas)
    assert np.array_equal(run.ads_q[meas], data.ads_q[0][meas])
    assert np.array_equal(run.ads_rate[meas], data.ads_rate[0][meas])
    assert np.isnan(run.ads_q[~meas]).all()
    if truth:
        assert run.truth is not None
        assert np.array_equal(run.truth.q, data.q_true[0])
        assert np.array_equal(run.truth.bias, data.bias[0])
        assert np.array_equal(run.truth.calib, data.calib[0])
    else:
        assert run.truth is None
    with pytest.raises(FileExistsError):
        write_recorded(path, data)


def lines_of(tmp_path: Path, sim, truth: bool = False) -> list[list[str]]:  # type: ignore[no-untyped-def]
    path = tmp_path / "ok.csv"
    write_recorded(path, sim, truth=truth)
    return [line.split(",") for line in path.read_text().splitlines()]


def cell(rows: list[list[str]], row: int, col: str, value: str) -> None:
    """Set data row ``row`` (1-based) of column ``col``."""
    rows[row][rows[0].index(col)] = value


def edit_quaternion(scale: float) -> Callable[[list[list[str]]], None]:
    def edit(rows: list[list[str]]) -> None:
        for c in ("ads_qx", "ads_qy", "ads_qz", "ads_qw"):
            j = rows[0].index(c)
            rows[7][j] = repr(float(rows[7][j]) * scale)

    return edit


def drop_column(name: str) -> Callable[[list[list[str]]], None]:
    def edit(rows: list[list[str]]) -> None:
        j = rows[0].index(name)
        for r in rows:
            del r[j]

    return edit


def add_column(name: str) -> Callable[[list[list[str]]], None]:
    def edit(rows: list[list[str]]) -> None:
        rows[0].append(name)
        for r in rows[1:]:
            r.append("0")

    return edit


BAD: dict[str, tuple[Callable[[list[list[str]]], None], str]] = {
    "missing column": (drop_column("gyro_wy_rad_s"), r"missing column gyro_wy_rad_s"),
    "unknown column": (add_column("temperature_c"), r"unknown column 'temperature_c'"),
    "text cell": (
        lambda r: cell(r, 5, "gyro_wy_rad_s", "abc"),
        r"row 5 \(line 6\), column gyro_wy_rad_s: 'abc' is not a number",
    ),
    "nan cell": (
        lambda r: cell(r, 9, "ads_wz_rad_s", "nan"),
        r"row 9 \(line 10\), column ads_wz_rad_s: nan",
    ),
    "empty gyro": (
        lambda r: cell(r, 4, "gyro_wx_rad_s", ""),
        r"row 4 \(line 5\), column gyro_wx_rad_s: empty",
    ),
    "time not increasing": (
        lambda r: cell(r, 12, "t_s", r[10][0]),
        r"row 12 \(line 13\), column t_s: .* strictly increasing",
    ),
    "non-unit quaternion": (
        edit_quaternion(1.0 + 1e-5),
        r"row 7 \(line 8\), column ads_qx, ads_qy, ads_qz, ads_qw: not a unit quaternion",
    ),
    "partly empty quaternion": (
        lambda r: cell(r, 3, "ads_qz", ""),
        r"row 3 \(line 4\), column ads_qz: ADS attitude partly empty",
    ),
    "partly empty rate": (
        lambda r: cell(r, 3, "ads_wx_rad_s", ""),
        r"row 3 \(line 4\), column ads_wx_rad_s: ADS rate partly empty",
    ),
    "deg/s rates": (
        lambda r: cell(r, 20, "gyro_wx_rad_s", "57.3"),
        r"row 20 \(line 21\), column gyro_wx_rad_s.*deg/s given\?",
    ),
    "header only": (lambda r: r.__delitem__(slice(1, None)), r"a header but no rows"),
    "partial truth": (add_column("true_qx"), r"truth columns are all or none; missing true_qy"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_names_file_row_and_column(tmp_path: Path, sim, case: str) -> None:  # type: ignore[no-untyped-def]
    edit, message = BAD[case]
    rows = lines_of(tmp_path, sim)
    edit(rows)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(",".join(r) for r in rows) + "\n")
    with pytest.raises(RecordedDataError, match=message) as err:
        read_recorded(bad)
    assert str(bad) in str(err.value)
    # the command line: exit 2, the message, nothing written
    out = tmp_path / "run"
    res = CliRunner().invoke(
        app,
        ["bench", "paper", "--set", "scenario.duration_s=60", "--data", str(bad),
         "--methods", "kf", "--out", str(out), "--quiet"],
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "bad.csv" in res.output and not out.exists()


def test_near_unit_quaternion_is_renormalised(tmp_path: Path, sim) -> None:  # type: ignore[no-untyped-def]
    rows = lines_of(tmp_path, sim)
    edit_quaternion(1.0 + 5e-7)(rows)
    path = tmp_path / "near.csv"
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")
    run = read_recorded(path)
    assert np.linalg.norm(run.ads_q[6]) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(run.ads_q[6], sim.ads_q[0, 6], atol=1e-15)


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_text("")
    with pytest.raises(RecordedDataError, match=r"empty\.csv: empty file"):
        read_recorded(path)


def test_epoch_limit_stops_before_the_end(tmp_path: Path, sim) -> None:  # type: ignore[no-untyped-def]
    """A file over the row limit is refused while streaming: a bad cell after the limit is
    never reached (the limit is what is reported)."""
    rows = lines_of(tmp_path, sim)
    big = [rows[0]]
    t0 = 0.0
    for _ in range(60):  # 3,600 rows
        for r in rows[1:]:
            r2 = list(r)
            r2[0] = repr(t0)
            t0 += 1.0
            big.append(r2)
    cell(big, len(big) - 1, "gyro_wx_rad_s", "oops")  # after the limit
    path = tmp_path / "long.csv"
    path.write_text("\n".join(",".join(r) for r in big) + "\n")
    from qkf.transfer_alignment.recorded import reader

    old = reader.BLOCK_BYTES
    reader.BLOCK_BYTES = 1 << 14  # small blocks, so the limit is crossed mid-file
    try:
        with pytest.raises(RecordedDataError, match=r"more than 1,000 rows: over the epoch"):
            read_recorded(path, ReadLimits(max_rows=1000))
    finally:
        reader.BLOCK_BYTES = old
    with pytest.raises(RecordedDataError, match=r"'oops' is not a number"):
        read_recorded(path)
    # through the config: recorded.max_epochs, exit 2
    res = CliRunner().invoke(
        app,
        ["bench", "paper", "--set", "recorded.max_epochs=1000", "--data", str(path),
         "--methods", "kf", "--out", str(tmp_path / "o"), "--quiet"],
    )  # fmt: skip
    assert res.exit_code == 2 and "over the epoch limit" in res.output


def test_parquet_with_text_and_with_strings(tmp_path: Path, sim) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "r.parquet"
    write_recorded(path, sim, truth=False)
    table = pq.read_table(path)
    col = [repr(v) for v in table.column("gyro_wz_rad_s").to_pylist()]
    col[8] = "x"
    table = table.set_column(table.schema.get_field_index("gyro_wz_rad_s"), "gyro_wz_rad_s",
                             pa.array(col))  # fmt: skip
    bad = tmp_path / "bad.parquet"
    pq.write_table(table, bad)
    with pytest.raises(RecordedDataError, match=r"row 9 \(line 10\), column gyro_wz_rad_s"):
        read_recorded(bad)


def test_data_files(tmp_path: Path, sim) -> None:  # type: ignore[no-untyped-def]
    for name in ("b.csv", "a.parquet", "notes.txt"):
        (tmp_path / name).write_text("x")
    assert [p.name for p in data_files([tmp_path])] == ["a.parquet", "b.csv"]
    with pytest.raises(RecordedDataError, match=r"not a \.csv"):
        data_files([tmp_path / "notes.txt"])
    with pytest.raises(RecordedDataError, match="given twice"):
        data_files([tmp_path / "b.csv", tmp_path / "b.csv"])
    with pytest.raises(RecordedDataError, match="no such data file"):
        data_files([tmp_path / "nope.csv"])
    assert set(REQUIRED_COLUMNS) < set(ALL_COLUMNS)
