"""The recorded-run file format (docs/recorded_data.md, "Input" and "Bad input"): the writer's
files read back bit for bit (CSV and Parquet, with and without truth), and every bad input is a
RecordedDataError naming the file, the row (with its CSV line) and the column; a file over the
epoch limit is refused while streaming. The command line's exit 2 for these errors is tested in
test_recorded_bench.py."""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.recorded import reader, writer
from qkf.transfer_alignment.recorded.columns import (
    ADS_Q,
    ALL_COLUMNS,
    REQUIRED_COLUMNS,
    TRUE_Q,
    TRUTH_COLUMNS,
)
from qkf.transfer_alignment.recorded.reader import (
    ReadLimits,
    RecordedDataError,
    RecordedRun,
    data_files,
    read_recorded,
)
from qkf.transfer_alignment.recorded.writer import simulate_to_file, write_recorded
from qkf.transfer_alignment.scenario import ScenarioData, simulate

Rows = list[list[str]]


@pytest.fixture(scope="module")
def cfg():  # type: ignore[no-untyped-def]
    return load_config("paper", ["scenario.duration_s=200"])


@pytest.fixture(scope="module")
def sim(cfg) -> ScenarioData:  # type: ignore[no-untyped-def]
    """Two trials, with epochs without an ADS measurement: empty ADS cells."""
    data = simulate(cfg, 3, [0, 1])
    meas = np.ones(data.n_epochs, dtype=bool)
    meas[10:14] = False
    meas[-1] = False
    return replace(data, has_meas=meas)


def bits(a: np.ndarray) -> np.ndarray:
    """The float64 bit patterns (so -0.0 and 0.0 differ, and NaN equals itself)."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def assert_run_is(run: RecordedRun, data: ScenarioData, row: int, truth: bool) -> None:
    meas = np.broadcast_to(data.has_meas, (data.n_trials, data.n_epochs))[row]
    assert run.n_rows == data.n_epochs
    assert np.array_equal(bits(run.t), bits(data.t))
    assert np.array_equal(bits(run.gyro), bits(data.gyro[row]))
    assert np.array_equal(run.has_attitude, meas) and np.array_equal(run.has_rate, meas)
    assert np.isnan(run.ads_q[~meas]).all() and np.isnan(run.ads_rate[~meas]).all()
    assert np.array_equal(bits(run.ads_rate[meas]), bits(data.ads_rate[row][meas]))
    # ads_q: the reader renormalises a quaternion only when its norm is more than 1e-15 off 1
    # (UNIT_ROUNDING); the simulated ones are unit to rounding, so they keep their bits. Were a
    # quaternion renormalised, the last bits could move: hence also the 1e-15 comparison.
    np.testing.assert_allclose(run.ads_q[meas], data.ads_q[row][meas], rtol=0, atol=1e-15)
    assert np.array_equal(bits(run.ads_q[meas]), bits(data.ads_q[row][meas]))
    assert np.all(np.abs(np.linalg.norm(run.ads_q[meas], axis=1) - 1) <= 1e-15)
    assert run.has_truth is truth
    if truth:
        assert run.truth is not None
        assert np.array_equal(bits(run.truth.q), bits(data.q_true[row]))
        assert np.array_equal(bits(run.truth.bias), bits(data.bias[row]))
        assert np.array_equal(bits(run.truth.calib), bits(data.calib[row]))
    else:
        assert run.truth is None
    assert run.sha256 == hashlib.sha256(run.path.read_bytes()).hexdigest()


# -- round trip --------------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".pq"])
@pytest.mark.parametrize("truth", [True, False])
def test_round_trip_is_bit_exact(
    tmp_path: Path, sim: ScenarioData, suffix: str, truth: bool
) -> None:
    path = tmp_path / f"r{suffix}"
    write_recorded(path, sim, 0, truth=truth)
    assert_run_is(read_recorded(path), sim, 0, truth)
    if suffix == ".csv":
        lines = path.read_text().splitlines()
        assert lines[0].split(",") == list(ALL_COLUMNS if truth else REQUIRED_COLUMNS)
        assert lines[11].split(",")[1:8] == [""] * 7  # row 11 = epoch 10: no ADS measurement
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temp file left


def test_round_trip_of_extreme_values_and_per_trial_mask(tmp_path: Path, sim: ScenarioData) -> None:
    """has_meas per trial (B, N); -0.0, subnormals and long mantissas keep their bits."""
    meas = np.ones((2, sim.n_epochs), dtype=bool)
    meas[1, 50:70] = False
    gyro = sim.gyro.copy()
    gyro[1, :5, 0] = [-0.0, 5e-324, 2.2250738585072014e-308, 0.1 + 0.2, 1 / 3]
    data = replace(sim, has_meas=meas, gyro=gyro)
    for suffix in (".csv", ".parquet"):
        path = tmp_path / f"trial1{suffix}"
        write_recorded(path, data, 1)
        assert_run_is(read_recorded(path), data, 1, truth=True)


@pytest.mark.parametrize("estimate", [None, 1, 10_000])
def test_small_batches_give_the_same_run(
    tmp_path: Path, sim: ScenarioData, monkeypatch: pytest.MonkeyPatch, estimate: int | None
) -> None:
    """Batches of a few rows; the CSV row estimate right, far too low (the arrays grow) or far
    too high (the result is copied out)."""
    monkeypatch.setattr(reader, "MIN_BLOCK_BYTES", 1)
    header = reader._csv_header
    if estimate is not None:
        monkeypatch.setattr(reader, "_csv_header", lambda p, lim: (*header(p, lim)[:3], estimate))
    for suffix in (".csv", ".parquet"):
        path = tmp_path / f"r{suffix}"
        write_recorded(path, sim)
        assert_run_is(read_recorded(path, ReadLimits(chunk_rows=7)), sim, 0, truth=True)


def test_blank_cells_are_empty(tmp_path: Path, sim: ScenarioData) -> None:
    """Cells of blanks are empty cells (the text read), quoted numbers numbers."""
    rows = csv_rows(tmp_path, sim)
    for r in rows[1:]:
        for j in range(1, 8):
            r[j] = "  " if r[j] == "" else f'"{r[j]}"'
    path = save(tmp_path / "blank.csv", rows)
    assert_run_is(read_recorded(path), sim, 0, truth=True)


def test_near_unit_quaternions_are_renormalised(tmp_path: Path, sim: ScenarioData) -> None:
    rows = csv_rows(tmp_path, sim)
    scale_quaternion(rows, 7, ADS_Q, 1.0 + 5e-7)
    scale_quaternion(rows, 9, TRUE_Q, 1.0 - 5e-7)
    run = read_recorded(save(tmp_path / "near.csv", rows))
    assert run.truth is not None
    assert abs(np.linalg.norm(run.ads_q[6]) - 1.0) <= 1e-15
    assert abs(np.linalg.norm(run.truth.q[8]) - 1.0) <= 1e-15
    np.testing.assert_allclose(run.ads_q[6], sim.ads_q[0, 6], rtol=0, atol=1e-15)
    np.testing.assert_allclose(run.truth.q[8], sim.q_true[0, 8], rtol=0, atol=1e-15)


def test_simulate_to_file_writes_the_trial_of_the_seed(tmp_path: Path, cfg, sim) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "trial1.parquet"
    simulate_to_file(cfg, 3, 1, path, truth=False)
    run = read_recorded(path)
    # a trial's streams are its own: trial 1 alone is trial 1 of the batch [0, 1]
    assert_run_is(run, replace(sim, has_meas=simulate(cfg, 3, [1]).has_meas), 1, truth=False)
    with pytest.raises(FileExistsError):
        simulate_to_file(cfg, 3, 1, path)


# -- the writer's safety -----------------------------------------------------------------------


def test_writer_never_overwrites_unless_asked(tmp_path: Path, sim: ScenarioData) -> None:
    path = tmp_path / "r.csv"
    path.write_text("mine\n")
    with pytest.raises(FileExistsError, match=r"r\.csv: exists"):
        write_recorded(path, sim)
    assert path.read_text() == "mine\n"
    old = os.umask(0o022)
    try:
        write_recorded(path, sim, overwrite=True)
    finally:
        os.umask(old)
    assert read_recorded(path).n_rows == sim.n_epochs
    assert path.stat().st_mode & 0o777 == 0o644  # the umask's, not mkstemp's 0600
    with pytest.raises(RecordedDataError, match=r"r\.txt: give a \.csv"):
        write_recorded(tmp_path / "r.txt", sim)
    with pytest.raises(IndexError, match="row 2"):
        write_recorded(tmp_path / "r2.csv", sim, 2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.csv"]


def test_writer_failure_leaves_no_file(tmp_path: Path, sim: ScenarioData, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    def half(table: pa.Table, sink, write_options=None) -> None:  # type: ignore[no-untyped-def]
        sink.write(b"0,1,2\n")
        raise OSError("disk full")

    monkeypatch.setattr(pacsv, "write_csv", half)
    with pytest.raises(OSError, match="disk full"):
        write_recorded(tmp_path / "r.csv", sim)
    assert list(tmp_path.iterdir()) == []


# -- bad input ---------------------------------------------------------------------------------


def csv_rows(tmp_path: Path, sim: ScenarioData, truth: bool = True) -> Rows:
    """The cells of trial 0 written as CSV: rows[0] the header, rows[k] data row k."""
    path = tmp_path / "ok.csv"
    if not path.exists():
        write_recorded(path, sim, truth=truth)
    return [line.split(",") for line in path.read_text().splitlines()]


def save(path: Path, rows: Rows) -> Path:
    path.write_text("".join(",".join(r) + "\n" for r in rows))
    return path


def set_cell(rows: Rows, row: int, col: str, value: str) -> None:
    rows[row][rows[0].index(col)] = value


def scale_quaternion(rows: Rows, row: int, names: tuple[str, ...], scale: float) -> None:
    for c in names:
        j = rows[0].index(c)
        rows[row][j] = repr(float(rows[row][j]) * scale)


def drop(*names: str) -> Callable[[Rows], None]:
    def edit(rows: Rows) -> None:
        for name in names:
            j = rows[0].index(name)
            for r in rows:
                del r[j]

    return edit


def add(name: str) -> Callable[[Rows], None]:
    def edit(rows: Rows) -> None:
        rows[0].append(name)
        for r in rows[1:]:
            r.append("0")

    return edit


def cell(row: int, col: str, value: str) -> Callable[[Rows], None]:
    return lambda rows: set_cell(rows, row, col, value)


def cells(row: int, cols: tuple[str, ...], value: str) -> Callable[[Rows], None]:
    def edit(rows: Rows) -> None:
        for c in cols:
            set_cell(rows, row, c, value)

    return edit


def repeat_time(row: int, of: int) -> Callable[[Rows], None]:
    return lambda rows: set_cell(rows, row, "t_s", rows[of][0])


def edits(*each: Callable[[Rows], None]) -> Callable[[Rows], None]:
    def edit(rows: Rows) -> None:
        for e in each:
            e(rows)

    return edit


def without_rows(rows: Rows) -> None:
    del rows[1:]


# case: (edit of the cells, what the message must hold besides the file's name)
BAD: dict[str, tuple[Callable[[Rows], None], list[str]]] = {
    "missing columns": (
        drop("gyro_wy_rad_s", "ads_qw"),
        ["missing column ads_qw, gyro_wy_rad_s"],
    ),
    "unknown column": (
        add("temperature_c"),
        ["unknown column 'temperature_c'", "the columns are t_s, ads_qx", "true_p_k_zy"],
    ),
    "duplicate column": (add("gyro_wx_rad_s"), ["'gyro_wx_rad_s' appears more than once"]),
    "partial truth": (
        drop("true_bias_y_rad_s", "true_p_k_zy"),
        ["truth columns are all or none; missing true_bias_y_rad_s, true_p_k_zy"],
    ),
    "header only": (without_rows, ["a header but no rows"]),
    "text": (
        cell(5, "gyro_wy_rad_s", "abc"),
        ["row 5 (line 6), column gyro_wy_rad_s: 'abc' is not a number"],
    ),
    "text in truth": (
        cell(150, "true_p_k_yx", "1.0.0"),
        ["row 150 (line 151), column true_p_k_yx: '1.0.0' is not a number"],
    ),
    "nan": (cell(9, "ads_wz_rad_s", "nan"), ["row 9 (line 10), column ads_wz_rad_s: nan is not"]),
    "inf": (cell(2, "gyro_wx_rad_s", "inf"), ["row 2 (line 3), column gyro_wx_rad_s: inf is not"]),
    "-inf in truth": (
        cell(4, "true_bias_z_rad_s", "-Infinity"),
        ["row 4 (line 5), column true_bias_z_rad_s: -inf is not a finite number"],
    ),
    "empty time": (cell(8, "t_s", ""), ["row 8 (line 9), column t_s: empty"]),
    "empty gyro": (cell(4, "gyro_wx_rad_s", ""), ["row 4 (line 5), column gyro_wx_rad_s: empty"]),
    "empty truth": (cell(6, "true_p_s_y", ""), ["row 6 (line 7), column true_p_s_y: empty"]),
    "empty truth quaternion": (
        cells(6, TRUE_Q, ""),
        ["row 6 (line 7), column true_qx: empty"],
    ),
    "time repeated": (
        repeat_time(12, 11),
        ["row 12 (line 13), column t_s: t = 10.0 s after t = 10.0 s in row 11", "strictly"],
    ),
    "time backwards": (
        repeat_time(40, 20),
        ["row 40 (line 41), column t_s: t = 19.0 s after t = 38.0 s in row 39", "strictly"],
    ),
    "partly empty quaternion": (
        cells(3, ("ads_qz", "ads_qx"), ""),
        ["row 3 (line 4), column ads_qx, ads_qz: ADS attitude partly empty"],
    ),
    "partly empty rate": (
        cell(3, "ads_wy_rad_s", ""),
        ["row 3 (line 4), column ads_wy_rad_s: ADS rate partly empty"],
    ),
    "non-unit quaternion": (
        lambda rows: scale_quaternion(rows, 7, ADS_Q, 1.0 + 1e-5),
        [
            "row 7 (line 8), column ads_qx, ads_qy, ads_qz, ads_qw: not a unit quaternion",
            "norm 1.0000",
        ],
    ),
    "non-unit truth quaternion": (
        lambda rows: scale_quaternion(rows, 30, TRUE_Q, 0.5),
        [
            "row 30 (line 31), column true_qx, true_qy, true_qz, true_qw: not a unit quaternion",
            "norm 0.5",
        ],
    ),
    "gyro in deg/s": (
        cell(20, "gyro_wx_rad_s", "57.3"),
        [
            "row 20 (line 21), column gyro_wx_rad_s, gyro_wy_rad_s, gyro_wz_rad_s",
            "rad/s: deg/s given?",
        ],
    ),
    "ads rate in deg/s": (
        cell(21, "ads_wz_rad_s", "-11"),
        [
            "row 21 (line 22), column ads_wx_rad_s, ads_wy_rad_s, ads_wz_rad_s",
            "rad/s: deg/s given?",
        ],
    ),
    "a short row": (
        lambda rows: rows[17].__delitem__(-1),
        ["row 17 (line 18): 26 cells, the header has 27"],
    ),
    "the first bad row of several": (
        edits(cell(90, "gyro_wx_rad_s", "x"), cell(60, "ads_qy", ""), repeat_time(70, 69)),
        ["row 60 (line 61), column ads_qy: ADS attitude partly empty"],
    ),
    "text after a time error": (
        edits(cell(90, "gyro_wx_rad_s", "x"), repeat_time(70, 69)),
        ["row 70 (line 71), column t_s"],
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_names_file_row_and_column(tmp_path: Path, sim: ScenarioData, case: str) -> None:
    edit, expected = BAD[case]
    rows = csv_rows(tmp_path, sim)
    edit(rows)
    bad = save(tmp_path / "bad.csv", rows)
    with pytest.raises(RecordedDataError) as err:
        read_recorded(bad)
    message = str(err.value)
    assert message.startswith(f"{bad}: "), message
    for part in expected:
        assert part in message, message


@pytest.mark.parametrize(
    ("name", "content", "expected"),
    [
        ("run.csv", None, "no such data file"),
        ("run.csv", b"", "empty file (0 bytes"),
        ("run.parquet", b"", "empty file (0 bytes"),
        ("run.csv", b"\n\n", "empty file"),
        ("run.csv", b"\nt_s\n", "line 1 is blank"),
        ("run.csv", b"t_\xb5s\n", "line 1: not UTF-8 text"),
        ("run.txt", b"t_s\n0\n", "not a .csv, .parquet or .pq file"),
        ("run.csv", "folder", "is a directory, not a data file"),
    ],
)
def test_missing_and_empty_files(
    tmp_path: Path, name: str, content: bytes | str | None, expected: str
) -> None:
    path = tmp_path / name
    if content == "folder":
        path.mkdir()
    elif isinstance(content, bytes):
        path.write_bytes(content)
    with pytest.raises(RecordedDataError, match="^" + str(path)) as err:
        read_recorded(path)
    assert expected in str(err.value)


def test_parquet_of_other_types(tmp_path: Path, sim: ScenarioData) -> None:
    """float32, integer and all-null columns are numbers (a file with no ADS rate at all)."""
    path = tmp_path / "r.parquet"
    write_recorded(path, sim, truth=False)
    table = pq.read_table(path)
    for name in ("ads_wx_rad_s", "ads_wy_rad_s", "ads_wz_rad_s"):
        j = table.schema.get_field_index(name)
        table = table.set_column(j, name, pa.nulls(table.num_rows))
    t = np.arange(table.num_rows, dtype=np.int64) * 2
    table = table.set_column(0, "t_s", pa.array(t))
    gyro = table.column("gyro_wx_rad_s").cast(pa.float32())
    table = table.set_column(table.schema.get_field_index("gyro_wx_rad_s"), "gyro_wx_rad_s", gyro)
    other = tmp_path / "other.parquet"
    pq.write_table(table, other)
    run = read_recorded(other)
    assert not run.has_rate.any() and np.array_equal(run.has_attitude, sim.has_meas)
    assert np.array_equal(run.t, t.astype(float))
    assert np.array_equal(run.gyro[:, 0], sim.gyro[0, :, 0].astype(np.float32).astype(float))


def test_line_numbers_count_blank_lines(tmp_path: Path, sim: ScenarioData) -> None:
    rows = csv_rows(tmp_path, sim)
    set_cell(rows, 30, "gyro_wz_rad_s", "1e5")
    text = "".join(",".join(r) + "\n" + ("\n" if k in (3, 10) else "") for k, r in enumerate(rows))
    bad = tmp_path / "blank_lines.csv"
    bad.write_text(text)
    with pytest.raises(
        RecordedDataError, match=r"blank_lines\.csv: row 30 \(line 33\), column gyro"
    ):
        read_recorded(bad)


def test_time_checked_across_batches(tmp_path: Path, sim: ScenarioData, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Batches of a few rows: a time step back is found wherever a batch boundary falls."""
    monkeypatch.setattr(reader, "MIN_BLOCK_BYTES", 1)  # CSV blocks of a few rows
    limits = ReadLimits(chunk_rows=5)
    for row in range(2, 14):
        rows = csv_rows(tmp_path, sim)
        repeat_time(row, row - 1)(rows)
        bad = save(tmp_path / "bad.csv", rows)
        with pytest.raises(RecordedDataError, match=rf"row {row} \(line {row + 1}\), column t_s"):
            read_recorded(bad, limits)
    # Parquet: batches of exactly chunk_rows rows; row 11 opens the third
    t = sim.t.copy()
    t[10] = t[9]
    path = tmp_path / "back.parquet"
    write_recorded(path, replace(sim, t=t))
    with pytest.raises(RecordedDataError, match=r"back\.parquet: row 11, column t_s: t = 9\.0 s"):
        read_recorded(path, limits)


def test_bad_parquet_cells(tmp_path: Path, sim: ScenarioData) -> None:
    path = tmp_path / "r.parquet"
    write_recorded(path, sim, truth=False)
    table = pq.read_table(path)
    col = [repr(v) for v in table.column("gyro_wz_rad_s").to_pylist()]
    col[8] = "x"
    j = table.schema.get_field_index("gyro_wz_rad_s")
    bad = tmp_path / "bad.parquet"
    pq.write_table(table.set_column(j, "gyro_wz_rad_s", pa.array(col)), bad)
    with pytest.raises(RecordedDataError, match=r"bad\.parquet: row 9, column gyro_wz_rad_s: 'x'"):
        read_recorded(bad)
    flags = pa.array([True] * table.num_rows)
    pq.write_table(table.set_column(j, "gyro_wz_rad_s", flags), bad)
    with pytest.raises(RecordedDataError, match=r"bad\.parquet: column gyro_wz_rad_s holds bool"):
        read_recorded(bad)
    pq.write_table(table.rename_columns([*table.column_names[:-1], "true_qx"]), bad)
    with pytest.raises(RecordedDataError, match=r"bad\.parquet: missing column gyro_wz_rad_s"):
        read_recorded(bad)
    (tmp_path / "junk.pq").write_bytes(b"not parquet")
    with pytest.raises(RecordedDataError, match=r"junk\.pq: not a readable Parquet file"):
        read_recorded(tmp_path / "junk.pq")


# -- the epoch limit ---------------------------------------------------------------------------


def test_epoch_limit_is_found_while_streaming(
    tmp_path: Path, sim: ScenarioData, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file over the row limit is refused after the batch that crosses it: the rows after
    that are never handed over, and a bad cell near the end is never reached."""
    header, *body = csv_rows(tmp_path, sim)
    rows, t = [header], 0.0
    for _ in range(20):  # 4,000 rows
        for r in body:
            rows.append([repr(t), *r[1:]])
            t += 1.0
    set_cell(rows, len(rows) - 2, "gyro_wx_rad_s", "oops")
    path = save(tmp_path / "long.csv", rows)
    with pytest.raises(RecordedDataError, match=r"long\.csv: row 3999 \(line 4000\), column gyro"):
        read_recorded(path)  # the bad cell is there
    batches: list[tuple[int, int]] = []  # (collector, rows): a read starts over as text
    add_batch = reader._Collector.add

    def counting(self, batch):  # type: ignore[no-untyped-def]
        batches.append((id(self), batch.num_rows))
        add_batch(self, batch)

    monkeypatch.setattr(reader._Collector, "add", counting)
    limits = ReadLimits(max_rows=1000, chunk_rows=100)
    with pytest.raises(RecordedDataError) as err:
        read_recorded(path, limits)
    assert str(err.value).startswith(f"{path}: more than 1,000 rows: over the epoch limit")
    handed = [n for who, n in batches if who == batches[-1][0]]
    assert sum(handed[:-1]) <= 1000 < sum(handed) < 1500  # stopped at the crossing batch
    # Parquet: the row count is in the file's footer; refused before reading a row
    batches.clear()
    pq_path = tmp_path / "long.parquet"
    pq.write_table(pacsv.read_csv(save(tmp_path / "long_ok.csv", rows[:-2])), pq_path)
    with pytest.raises(RecordedDataError, match=r"long\.parquet: more than 1,000 rows"):
        read_recorded(pq_path, limits)
    assert batches == []
    assert read_recorded(pq_path, ReadLimits(max_rows=3998)).n_rows == 3998


# -- data_files --------------------------------------------------------------------------------


def test_data_files(tmp_path: Path) -> None:
    for name in ("b.csv", "a.parquet", "C.PQ", "notes.txt"):
        (tmp_path / name).write_text("x")
    (tmp_path / "sub.csv").mkdir()
    assert [p.name for p in data_files([tmp_path])] == ["C.PQ", "a.parquet", "b.csv"]
    assert data_files([tmp_path / "b.csv", str(tmp_path / "a.parquet")]) == [
        tmp_path / "b.csv",
        tmp_path / "a.parquet",
    ]
    refused = {
        "unsupported": ([tmp_path / "notes.txt"], r"notes\.txt: not a \.csv, \.parquet or \.pq"),
        "twice": ([tmp_path / "b.csv", tmp_path / "b.csv"], r"b\.csv: given twice"),
        "file and its folder": ([tmp_path / "b.csv", tmp_path], r"b\.csv: given twice"),
        "missing": ([tmp_path / "nope.csv"], r"nope\.csv: no such data file"),
        "empty folder": ([tmp_path / "sub.csv"], r"sub\.csv: a folder without \.csv"),
        "nothing": ([], "no data file given"),
    }
    for given, match in refused.values():
        with pytest.raises(RecordedDataError, match=match):
            data_files(given)
    assert set(REQUIRED_COLUMNS) | set(TRUTH_COLUMNS) == set(ALL_COLUMNS)


def test_writer_module_exports() -> None:
    assert writer.write_recorded is write_recorded and callable(writer.recorded_table)


def test_text_that_is_not_utf8_is_named(tmp_path: Path, sim: ScenarioData) -> None:
    rows = csv_rows(tmp_path, sim)
    data = "".join(",".join(r) + "\n" for r in rows).encode()
    start = data.index(rows[120][5].encode(), len("".join(",".join(r) + "\n" for r in rows[:120])))
    bad = tmp_path / "latin1.csv"
    bad.write_bytes(data[:start] + b"\xb5" + data[start:])
    with pytest.raises(
        RecordedDataError, match=r"latin1\.csv: row 120 \(line 121\), column ads_wx"
    ):
        read_recorded(bad)


@pytest.mark.parametrize("case", list(BAD))
def test_every_bad_input_exits_2_on_the_command_line(
    tmp_path: Path, sim: ScenarioData, case: str
) -> None:
    """Through ``qkf bench --data``: exit 2, the file named, nothing written."""
    edit, _ = BAD[case]
    rows = csv_rows(tmp_path, sim)
    edit(rows)
    bad = save(tmp_path / "bad.csv", rows)
    out = tmp_path / "run"
    res = CliRunner().invoke(
        app,
        ["bench", "paper", "--set", "scenario.duration_s=60", "--data", str(bad),
         "--methods", "kf", "--out", str(out), "--quiet"],
    )  # fmt: skip
    assert res.exit_code == 2, res.output
    assert "bad.csv" in res.output and not out.exists()


def test_the_epoch_limit_is_set_in_the_config(tmp_path: Path, sim: ScenarioData) -> None:
    path = tmp_path / "r.csv"
    write_recorded(path, sim)
    res = CliRunner().invoke(
        app,
        ["bench", "paper", "--set", "recorded.max_epochs=10", "--data", str(path),
         "--methods", "kf", "--out", str(tmp_path / "o"), "--quiet"],
    )  # fmt: skip
    assert res.exit_code == 2 and "epoch limit" in res.output, res.output
