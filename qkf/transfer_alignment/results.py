"""The results format of a transfer-alignment bench, written and read back: the folder
``qkf bench`` writes (the CSV tables of :mod:`.report`, the figures of :mod:`.bench_figures`,
``run.json``), :func:`load_bench` that reads it back for a study, a zoo card or a redraw, and
``crlb.csv``. Every reader names the file and line of what it cannot use."""

from __future__ import annotations

import csv
from collections import defaultdict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.config import ConfigError, validate
from qkf.core.io import atomic_write_bytes, staged_directory
from qkf.core.manifest import manifest, read_manifest, write_manifest
from qkf.transfer_alignment.bench_figures import bench_figures
from qkf.transfer_alignment.benchmark import NEES_COLUMNS, BenchResult, MethodResult
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import CrlbResult
from qkf.transfer_alignment.metrics import METRIC_COLUMNS
from qkf.transfer_alignment.report import (
    BAND_COLUMNS,
    INTERVAL_COLUMNS,
    NEES_FILE_COLUMNS,
    TRIAL_COLUMNS,
    bench_tables,
    crlb_csv_text,
)
from qkf.transfer_alignment.states import DISPLAY_UNIT, GROUP_TITLES, STATE_COLUMNS


def write_crlb_csv(path: str | Path, result: CrlbResult) -> None:
    """Write :func:`crlb_csv_text` to ``path`` atomically."""
    atomic_write_bytes(path, crlb_csv_text(result).encode())


def bench_manifest(res: BenchResult, command: list[str] | None = None) -> dict[str, Any]:
    """``run.json`` of a benchmark (docs/architecture.md, "Output files")."""
    return manifest(
        "bench",
        res.config.model_dump(mode="json"),
        command,
        methods=[{"name": m.name, "spec": m.spec} for m in res.methods],
        trials=res.trials,
        seed=res.seed,
        backend=res.backend,
        workers=res.workers,
        cache=res.cache,
    )


def write_bench(
    res: BenchResult, out_dir: str | Path, command: list[str] | None = None
) -> list[Path]:
    """Write the files of a benchmark into ``out_dir``, replacing any earlier run there whole.

    Everything is rendered in memory first, written into a staging directory beside
    ``out_dir`` and swapped in when complete (:func:`qkf.core.io.staged_directory`).
    """
    files = {**bench_tables(res), **bench_figures(res)}
    out = Path(out_dir)
    with staged_directory(out) as stage:
        for name, content in files.items():
            atomic_write_bytes(stage / name, content)
        write_manifest(stage, bench_manifest(res, command))
    return [out / name for name in (*files, "run.json")]


@dataclass(frozen=True)
class _Row:
    """One data row of a result CSV read back, with where it came from (for messages)."""

    path: Path
    line: int  # 1-based line of the file (the header is line 1)
    cells: dict[str, str]

    def text(self, col: str) -> str:
        return self.cells[col]

    def num(self, col: str, blank: float | None = None) -> float:
        """The cell as a number; ``blank``: the value of an empty cell (else it is an error)."""
        raw = self.cells[col]
        if raw == "" and blank is not None:
            return blank
        try:
            return float(raw)
        except ValueError:
            raise ConfigError(
                f"{self.path}: line {self.line}: {col}: {raw!r} is not a number "
                "(a truncated or corrupt file?)"
            ) from None

    def integer(self, col: str) -> int:
        value = self.num(col)
        if not value.is_integer():
            raise ConfigError(f"{self.path}: line {self.line}: {col}: {value:g} is not an integer")
        return int(value)


def checked_rows(
    path: Path, what: str, header_problem: Callable[[list[str]], str | None]
) -> Iterator[tuple[list[str], int, list[str]]]:
    """``(header, line, cells)`` for each data row of a CSV file qkf wrote, every row as long
    as the header. ``ConfigError`` naming the file (and the line) for a missing file, a header
    ``header_problem`` refuses (it returns the message, or None), a row with too few or too
    many cells (a truncated file), bad bytes or broken CSV; ``what`` names the folder the file
    belongs to in the messages (``qkf bench folder``)."""
    if not path.is_file():
        raise ConfigError(f"{path}: missing (not a complete {what})")
    try:
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None) or []
            problem = header_problem(header)
            if problem is not None:
                raise ConfigError(f"{path}: {problem}")
            for cells in reader:
                if len(cells) != len(header):
                    raise ConfigError(
                        f"{path}: line {reader.line_num}: {len(cells)} cells where the header "
                        f"has {len(header)} (a truncated or corrupt file?)"
                    )
                yield header, reader.line_num, cells
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a text file (a corrupt file?)") from None
    except csv.Error as exc:
        raise ConfigError(f"{path}: not a readable CSV file ({exc})") from None


def _read_rows(path: Path, columns: tuple[str, ...] = ()) -> list[_Row]:
    """The data rows of a result CSV, checked (:func:`checked_rows`): a missing column is an
    error too."""

    def header_problem(header: list[str]) -> str | None:
        if not header:
            return "empty (not a complete qkf bench folder)"
        missing = [c for c in columns if c not in header]
        return f"line 1: no column {', '.join(missing)}" if missing else None

    rows = checked_rows(path, "qkf bench folder", header_problem)
    return [_Row(path, line, dict(zip(header, cells, strict=True))) for header, line, cells in rows]


def read_trials_csv(folder: str | Path) -> dict[str, np.ndarray]:
    """``trials.csv`` of a bench folder read back: per method, the per-trial metric values
    (trials, K) in :data:`METRIC_COLUMNS` order, rows in trial order. ``ConfigError`` names the
    file and line of anything that cannot be read."""
    path = Path(folder) / "trials.csv"
    per: dict[str, list[tuple[int, list[float]]]] = defaultdict(list)
    for r in _read_rows(path, TRIAL_COLUMNS):
        per[r.text("method")].append((r.integer("trial"), [r.num(c) for c in METRIC_COLUMNS]))
    return {m: np.array([v for _, v in sorted(rows)]) for m, rows in per.items()}


def read_crlb_csv(path: str | Path) -> CrlbResult:
    """A ``crlb.csv`` read back (SI), its covariance left empty; ``ConfigError`` names the file
    and the line of a bad row."""
    rows = _read_rows(Path(path), ("t_s", *STATE_COLUMNS))
    if not rows:
        raise ConfigError(f"{path}: no rows (a truncated file?)")
    t = np.array([r.num("t_s") for r in rows])
    bound = np.array([[r.num(c) for c in STATE_COLUMNS] for r in rows]) * DISPLAY_UNIT
    return CrlbResult(t=t, bound=bound, cov=np.empty((0, 15, 15)))


def load_bench(folder: str | Path) -> BenchResult:
    """A finished benchmark read back from its files (``run.json``, ``rms.csv``, ``crlb.csv``,
    ``summary.csv``, ``kappa.csv``), for redrawing its figures. ``ConfigError`` names the file
    and the line of anything that cannot be read (a truncated or corrupt file)."""
    folder = Path(folder)
    info = read_manifest(folder, "bench")
    cfg = validate(Config, info["config"], str(folder / "run.json"), "configuration")
    unit = DISPLAY_UNIT
    bound = read_crlb_csv(folder / "crlb.csv")
    t = bound.t
    per_method: dict[str, list[list[float]]] = defaultdict(list)
    rms_path = folder / "rms.csv"
    for r in _read_rows(rms_path, ("method", *STATE_COLUMNS)):
        per_method[r.text("method")].append([r.num(c) for c in STATE_COLUMNS])
    kappa: dict[str, dict[int, list[float]]] = defaultdict(lambda: defaultdict(list))
    kappa_t: list[float] = []
    if (folder / "kappa.csv").is_file():
        for r in _read_rows(folder / "kappa.csv", ("method", "trial", "t_s", "kappa")):
            kappa[r.text("method")][r.integer("trial")].append(r.num("kappa"))
            if not kappa_t or r.num("t_s") > kappa_t[-1]:
                kappa_t.append(r.num("t_s"))
    bands, band_t = _read_bands(folder / "rms_bands.csv")
    nees, nees_t = _read_nees(folder / "nees.csv")
    methods = []
    summary_cols = ("method", "trials", "diverged", "runtime_s", *INTERVAL_COLUMNS)
    for r in _read_rows(folder / "summary.csv", summary_cols):
        name = r.text("method")
        # a short method (rows lost at the end of rms.csv) would plot a curve that stops early
        if len(per_method.get(name, [])) != t.size:
            raise ConfigError(
                f"{rms_path}: method {name}: {len(per_method.get(name, []))} rows where crlb.csv "
                f"has {t.size} epochs (a truncated file?)"
            )
        traces = kappa.get(name)
        if traces and len({len(v) for v in traces.values()} | {len(kappa_t)}) > 1:
            raise ConfigError(f"{folder / 'kappa.csv'}: method {name}: traces of unequal length "
                              "(a truncated file?)")  # fmt: skip
        methods.append(
            MethodResult(
                name=name,
                rms=np.array(per_method[name]) * unit,
                trials=r.integer("trials"),
                diverged=r.integer("diverged"),
                runtime_s=r.num("runtime_s"),
                summary={
                    c: r.num(c, blank=float("nan")) if c in r.cells else float("nan")
                    for c in (*INTERVAL_COLUMNS, *NEES_COLUMNS)
                },
                kappa=np.array([traces[i] for i in sorted(traces)]) if traces else None,
                band=bands.get(name),
                nees=nees.get(name, (None, None))[0],
                nees_trials=nees.get(name, (None, None))[1],
            )
        )
    return BenchResult(
        config=cfg,
        seed=int(info["seed"]),
        trials=int(info["trials"]),
        t=t,
        methods=methods,
        bound=bound,
        kappa_t=np.array(kappa_t),
        backend=str(info.get("backend", "local")),
        workers=int(info.get("workers", 1)),
        band_t=band_t,
        nees_t=nees_t,
    )


def _read_bands(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """rms_bands.csv back as (T, groups, 3) per method (absent file: no bands)."""
    if not path.is_file():
        return {}, np.empty(0)
    rows = _read_rows(path, BAND_COLUMNS)
    groups = list(GROUP_TITLES)
    t = np.unique([r.num("t_s") for r in rows])
    out: dict[str, np.ndarray] = {}
    for r in rows:
        if r.text("group") not in groups:
            raise ConfigError(f"{path}: line {r.line}: group: {r.text('group')!r} is not one of "
                              f"{', '.join(groups)}")  # fmt: skip
        band = out.setdefault(r.text("method"), np.full((t.size, len(groups), 3), np.nan))
        k = int(np.searchsorted(t, r.num("t_s")))
        band[k, groups.index(r.text("group"))] = [r.num("rms"), r.num("lo"), r.num("hi")]
    return out, t


def _read_nees(path: Path) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """nees.csv back as (NEES, trials) per method (absent file: none)."""
    if not path.is_file():
        return {}, np.empty(0)
    per: dict[str, list[tuple[float, float, int]]] = defaultdict(list)
    for r in _read_rows(path, NEES_FILE_COLUMNS):
        per[r.text("method")].append((r.num("t_s"), r.num("nees"), r.integer("trials")))
    if len({len(v) for v in per.values()}) > 1:
        raise ConfigError(f"{path}: methods with unequal numbers of rows (a truncated file?)")
    out = {
        m: (np.array([v[1] for v in vals]), np.array([v[2] for v in vals]))
        for m, vals in per.items()
    }
    t = np.array([v[0] for v in next(iter(per.values()))]) if per else np.empty(0)
    return out, t


def redraw_bench(*folders: str | Path) -> list[Path]:
    """Redraw every figure of finished benchmarks (a sweep's folders, say) from their files;
    returns the figures. Every folder is read and rendered before the first file is written,
    so a truncated or corrupt file (``ConfigError``) leaves every figure as it was."""
    rendered = [(Path(f), bench_figures(load_bench(f))) for f in folders]
    written = []
    for folder, figures in rendered:
        for name, content in figures.items():
            atomic_write_bytes(folder / name, content)
            written.append(folder / name)
    return written


__all__ = [
    "bench_manifest",
    "checked_rows",
    "load_bench",
    "read_crlb_csv",
    "read_trials_csv",
    "redraw_bench",
    "write_bench",
    "write_crlb_csv",
]
