"""Recorded-data input of ``qkf fuse``, ``qkf align`` and ``qkf gyros run --data`` (issue 18):
a file the run cannot use is refused before any work — exit 2, one ``error:`` message naming the
file and the problem (row and column where there is one), plain numbers, ``--out`` never made.

The bad files are corrupted copies of good ones written from each package's own simulation;
the fusion arcs are 200 s long so that the few runs that do go ahead take about a second.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from qkf.alignment.config import load_config as load_alignment
from qkf.alignment.data import write_data_text
from qkf.alignment.scenario import simulate as simulate_alignment
from qkf.cli import app
from qkf.redundant_gyros import load_config as load_gyros
from qkf.redundant_gyros.pipeline import simulate_run
from qkf.sca_fusion.config import load_config as load_fusion
from qkf.sca_fusion.data import MIN_OVERLAP_FRACTION
from qkf.sca_fusion.scenario import simulate as simulate_fusion

runner = CliRunner()
SCA_HEADER = ["t_s", "q_x", "q_y", "q_z", "q_w"]
ACC_HEADER = ["t_s", "dw_x", "dw_y", "dw_z"]
FUSION_S = 200.0  # s, the simulated arc (1 Hz): 201 epochs per file
Rows = tuple[np.ndarray, np.ndarray]  # (SCA rows (n, 5), ACC rows (n, 4))


def invoke(args: list[str]) -> tuple[int, str]:
    """Exit code and the output on one line (rich wraps long messages)."""
    res = runner.invoke(app, args)
    return res.exit_code, " ".join(res.output.split())


def write_csv(path: Path, header: list[str], rows: np.ndarray | list[list[object]]) -> Path:
    """A CSV file with full-precision numbers (``repr`` of a float reads back the same)."""
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in rows:
            w.writerow([repr(float(v)) if isinstance(v, float | np.floating) else v for v in row])
    return path


def assert_refused(code: int, text: str, path: Path, *parts: str, out: Path) -> None:
    """Exit 2, a single ``error:`` message naming ``path`` and every part, ``out`` not made."""
    assert code == 2, text
    assert text.count("error:") == 1, text
    assert str(path) in text, text  # error messages are never wrapped (soft_wrap)
    for part in parts:
        assert part in text, (part, text)
    assert "np.float64" not in text and "np.int64" not in text, text
    assert not out.exists()


# --- qkf fuse --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fusion_rows() -> Rows:
    """(SCA rows (201, 5), ACC rows (201, 4)) of a 200-s simulated arc without gaps."""
    cfg = load_fusion(
        "sca_acc_fusion",
        [f"simulation.duration_s={FUSION_S}", "simulation.sca_gaps=[]", "simulation.data_gaps=[]"],
    )
    sim = simulate_fusion(cfg.simulation)
    return np.column_stack([sim.sca_t, sim.sca_q]), np.column_stack([sim.acc_t, sim.acc])


def fuse(tmp_path: Path, sca: Path, acc: Path) -> tuple[int, str, Path]:
    out = tmp_path / "out"
    code, text = invoke(
        ["fuse", "sca_acc_fusion", "--sca", str(sca), "--acc", str(acc), "--out", str(out)]
    )
    return code, text, out


def test_fuse_sca_of_one_row_is_refused(tmp_path: Path, fusion_rows: Rows) -> None:
    sca_rows, acc_rows = fusion_rows
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, sca_rows[:1])
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, acc_rows)
    code, text, out = fuse(tmp_path, sca, acc)
    # today's default: arcs.min_epochs 10, interpolation degree 2 → 10 epochs
    assert_refused(code, text, sca, "1 data row", "at least 10 star-camera epochs", out=out)


def test_fuse_acc_with_too_few_rows_is_refused(tmp_path: Path, fusion_rows: Rows) -> None:
    sca_rows, acc_rows = fusion_rows
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, sca_rows)
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, acc_rows[::40])  # 6 rows over the arc
    code, text, out = fuse(tmp_path, sca, acc)
    assert_refused(code, text, acc, "6 data rows", "accelerometer epochs", out=out)


def test_fuse_sca_in_milliseconds_is_refused(tmp_path: Path, fusion_rows: Rows) -> None:
    sca_rows, acc_rows = fusion_rows
    ms = sca_rows.copy()
    ms[:, 0] *= 1000.0
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, ms)
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, acc_rows)
    code, text, out = fuse(tmp_path, sca, acc)
    # the star camera is blamed (its span is the odd one), not the accelerometer
    assert text.index(str(sca)) < text.index(str(acc)), text
    assert_refused(
        code,
        text,
        sca,
        "column t_s: spans 200000 s",
        "10^3 times the 200 s",
        "milliseconds",
        out=out,
    )


def test_fuse_acc_covering_a_small_part_is_refused(tmp_path: Path, fusion_rows: Rows) -> None:
    sca_rows, acc_rows = fusion_rows
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, sca_rows)
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, acc_rows[:21])  # 0 … 20 s of 200 s
    code, text, out = fuse(tmp_path, sca, acc)
    assert_refused(
        code,
        text,
        acc,
        f"{acc}: covers 20 s of the 200 s the star camera covers (10 %",
        f"at least {100 * MIN_OVERLAP_FRACTION:.3g} %",
        out=out,
    )


def test_fuse_disjoint_times_are_refused(tmp_path: Path, fusion_rows: Rows) -> None:
    sca_rows, acc_rows = fusion_rows
    later = acc_rows.copy()
    later[:, 0] += 2 * FUSION_S  # the right data of another time
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, sca_rows)
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, later)
    code, text, out = fuse(tmp_path, sca, acc)
    assert_refused(
        code,
        text,
        acc,
        "do not overlap in time",
        f"{sca}: t_s 0 to 200 s",
        f"{acc}: t_s 400 to 600 s",
        out=out,
    )


def test_fuse_partial_coverage_above_the_threshold_still_runs(
    tmp_path: Path, fusion_rows: Rows
) -> None:
    """The coverage rule refuses wrong files, not an instrument that stopped early: the
    accelerometer over the first 70 % of the star camera's arc is fused (exit 0)."""
    sca_rows, acc_rows = fusion_rows
    keep = int(0.7 * FUSION_S) + 1
    assert keep / acc_rows.shape[0] > MIN_OVERLAP_FRACTION
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, sca_rows)
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, acc_rows[:keep])
    code, text, out = fuse(tmp_path, sca, acc)
    assert code == 0, text
    assert (out / "fused.csv").is_file()


@pytest.mark.parametrize(
    ("which", "column"), [("sca", "t_s"), ("sca", "q_w"), ("acc", "t_s"), ("acc", "dw_y")]
)
def test_fuse_duplicate_column_is_refused(
    tmp_path: Path, fusion_rows: Rows, which: str, column: str
) -> None:
    sca_rows, acc_rows = fusion_rows
    header, rows = (SCA_HEADER, sca_rows) if which == "sca" else (ACC_HEADER, acc_rows)
    # the copy holds the same numbers: a duplicate is refused whatever it holds
    doubled = np.column_stack([rows, rows[:, header.index(column)]])
    bad = write_csv(tmp_path / f"{which}.csv", [*header, column], doubled)
    good = write_csv(
        tmp_path / f"{'acc' if which == 'sca' else 'sca'}.csv",
        ACC_HEADER if which == "sca" else SCA_HEADER,
        acc_rows if which == "sca" else sca_rows,
    )
    sca, acc = (bad, good) if which == "sca" else (good, bad)
    code, text, out = fuse(tmp_path, sca, acc)
    n = len(header) + 1
    assert_refused(
        code,
        text,
        bad,
        f"line 1: column {column} appears twice in the header",
        f"fields {header.index(column) + 1} and {n}",
        out=out,
    )


@pytest.mark.parametrize("which", ["sca", "acc"])
def test_fuse_directory_or_missing_file_is_refused(
    tmp_path: Path, fusion_rows: Rows, which: str
) -> None:
    sca_rows, acc_rows = fusion_rows
    sca = write_csv(tmp_path / "SCA.csv", SCA_HEADER, sca_rows)
    acc = write_csv(tmp_path / "ACC.csv", ACC_HEADER, acc_rows)
    folder = tmp_path / "folder"
    folder.mkdir()
    for bad, message in (
        (folder, "is a directory, not a data file"),
        (tmp_path / "no.csv", "no such data file"),
    ):
        args = (bad, acc) if which == "sca" else (sca, bad)
        code, text, out = fuse(tmp_path, *args)
        assert_refused(code, text, bad, f"{bad}: {message}", out=out)


# --- qkf align -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def alignment_text() -> str:
    """A valid DATA.csv of the preset's sensors (30 epochs, rows in time order)."""
    cfg = load_alignment("alignment_three_sensors", ["simulation.epochs=30"])
    obs, _ = simulate_alignment(cfg)
    return write_data_text(obs)


def align(tmp_path: Path, data: Path) -> tuple[int, str, Path]:
    out = tmp_path / "out"
    code, text = invoke(
        ["align", "alignment_three_sensors", "--data", str(data), "--out", str(out), "--no-plot"]
    )
    return code, text, out


def test_align_time_going_back_is_refused_naming_the_row(
    tmp_path: Path, alignment_text: str
) -> None:
    lines = alignment_text.splitlines()
    # swap data rows 4 and 10 (file lines 5 and 11): row 4 is then later than row 5
    lines[4], lines[10] = lines[10], lines[4]
    t4, t5 = lines[4].split(",")[0], lines[5].split(",")[0]
    assert float(t4) > float(t5)
    data = tmp_path / "data.csv"
    data.write_text("\n".join(lines) + "\n")
    code, text, out = align(tmp_path, data)
    assert_refused(
        code,
        text,
        data,
        f"row 5 (line 6), column t_s: time {t5} is earlier than {t4} (row 4)",
        "in time order",
        out=out,
    )


def test_align_duplicate_column_is_refused(tmp_path: Path, alignment_text: str) -> None:
    lines = alignment_text.splitlines()
    # a second w_x column holding the same values: refused whatever it holds
    doubled = [f"{line},{line.split(',')[2]}" for line in lines]
    assert doubled[0].endswith(",r_z,w_x")
    data = tmp_path / "data.csv"
    data.write_text("\n".join(doubled) + "\n")
    code, text, out = align(tmp_path, data)
    assert_refused(
        code, text, data, "line 1: column w_x appears twice in the header (fields 3 and 9)", out=out
    )


def test_align_directory_or_missing_file_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "folder"
    folder.mkdir()
    for bad, message in (
        (folder, "is a directory, not a data file"),
        (tmp_path / "no.csv", "no such data file"),
    ):
        code, text, out = align(tmp_path, bad)
        assert_refused(code, text, bad, f"{bad}: {message}", out=out)


def test_align_accepts_what_is_not_a_problem(tmp_path: Path, alignment_text: str) -> None:
    """Rows of one epoch in any sensor order (equal t_s), a duplicated column it does not read,
    and a spreadsheet's byte-order mark: the run goes ahead (exit 0)."""
    lines = alignment_text.splitlines()
    first = lines[1].split(",")[0]
    epoch = [k for k, line in enumerate(lines) if k > 0 and line.split(",")[0] == first]
    assert len(epoch) >= 2
    lines[epoch[0]], lines[epoch[-1]] = lines[epoch[-1]], lines[epoch[0]]
    lines = [f"{line},note,note" if k == 0 else f"{line},x,y" for k, line in enumerate(lines)]
    data = tmp_path / "data.csv"
    data.write_text("\ufeff" + "\n".join(lines) + "\n", encoding="utf-8")
    code, text, out = align(tmp_path, data)
    assert code == 0, text
    assert (out / "alignment.csv").is_file()


# --- qkf gyros run --data --------------------------------------------------------------------


@pytest.fixture(scope="module")
def gyro_rows() -> tuple[list[str], np.ndarray]:
    """(header, rows): 20 s of simulated readings of five_gyros (t_s and one column per id)."""
    cfg = load_gyros("five_gyros", ["scenario.duration_s=20"])
    data = simulate_run(cfg, seed=1)
    return ["t_s", *cfg.unit.ids()], np.column_stack([data.t, data.meas[0]])


def gyros(tmp_path: Path, data: Path) -> tuple[int, str, Path]:
    out = tmp_path / "out"
    code, text = invoke(["gyros", "run", "five_gyros", "--data", str(data), "--out", str(out)])
    return code, text, out


def test_gyros_time_error_prints_plain_numbers(
    tmp_path: Path, gyro_rows: tuple[list[str], np.ndarray]
) -> None:
    header, rows = gyro_rows
    bad = rows.copy()
    bad[5, 0] = bad[7, 0]  # data row 6 (file line 7) jumps ahead: row 7 (line 8) goes back
    data = write_csv(tmp_path / "d.csv", header, bad)
    code, text, out = gyros(tmp_path, data)
    t6, t7 = repr(float(bad[6, 0])), repr(float(bad[5, 0]))  # as the file writes them
    assert_refused(
        code,
        text,
        data,
        f"line 8: column t_s: time does not increase ({t6} after {t7} on line 7)",
        out=out,
    )


def test_gyros_duplicate_column_is_refused(
    tmp_path: Path, gyro_rows: tuple[list[str], np.ndarray]
) -> None:
    header, rows = gyro_rows
    data = write_csv(tmp_path / "d.csv", [*header, "S"], np.column_stack([rows, rows[:, 4]]))
    code, text, out = gyros(tmp_path, data)
    assert_refused(
        code, text, data, "line 1: column S appears twice in the header (fields 5 and 7)", out=out
    )


def test_gyros_directory_or_missing_file_is_refused(tmp_path: Path) -> None:
    folder = tmp_path / "folder"
    folder.mkdir()
    for bad, message in (
        (folder, "is a directory, not a data file"),
        (tmp_path / "no.csv", "no such data file"),
    ):
        code, text, out = gyros(tmp_path, bad)
        assert_refused(code, text, bad, f"{bad}: {message}", out=out)
