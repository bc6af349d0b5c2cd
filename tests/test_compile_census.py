"""benchmarks/compile_census.py's report, from compile logs written by hand."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _census():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location(
        "compile_census", ROOT / "benchmarks" / "compile_census.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_report_sums_top_level_compiles_and_splits_row_loops(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sig = "(int64,)"
    # process 1: the routine (6 s) compiled inside its parallel loop (10 s), then a helper
    (tmp_path / "1.tsv").write_text(
        f"6.000\t1\tm.solve\tt::a\t{sig}\n10.000\t0\tm.solve_rows\tt::a\t{sig}\n"
        f"0.500\t0\tm.helper\tt::b\t{sig}\n"
    )
    # process 2: the same loop again, its routine loaded from the cache
    (tmp_path / "2.tsv").write_text(f"9.000\t0\tm.solve_rows\tt::c\t{sig}\n")
    _census().report(tmp_path, top=5)
    out = capsys.readouterr().out
    assert "top-level compile time: 19.5 s over 2 processes" in out
    assert "m.solve_rows  (routine 6.0 s, loop 4.0 s)" in out
    assert "m.solve_rows  (routine 0.0 s, loop 9.0 s)" in out
    assert "compiled by more than one process: 9.0 s paid again" in out
    assert "m.helper" in out.split("row loops")[0]  # among the costliest, not a row loop
    assert "m.helper" not in out.split("row loops")[1]


def test_report_refuses_a_folder_without_logs(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="no compile logs"):
        _census().report(tmp_path, top=5)
