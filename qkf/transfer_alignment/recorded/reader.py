"""Reading a recorded run, streamed in blocks of rows, every bad input refused with the file,
row and column named (docs/recorded_data.md, "Bad input").

CSV is read with pyarrow's streaming reader, every column as text first: the conversion to
float64 is one vectorised cast per column, and only when a cast fails is the block searched
cell by cell for the first bad one (so the message can name it). Parquet is read with
``ParquetFile.iter_batches``. At most one block of rows is held beside the growing result.
Rows are numbered from 1 after the header; messages say ``FILE: row R (line R+1), column C``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from qkf.core.config import ConfigError
from qkf.core.csvfile import where
from qkf.transfer_alignment.recorded.columns import (
    ADS_Q,
    ADS_RATE,
    ALL_COLUMNS,
    EXTENSIONS,
    GYRO,
    OPTIONAL_GROUPS,
    QUATERNIONS,
    RATE_COLUMNS,
    REQUIRED_COLUMNS,
    TIME,
    TRUE_BIAS,
    TRUE_P,
    TRUE_Q,
    TRUTH_COLUMNS,
)

BLOCK_BYTES = 1 << 24
"""Bytes per CSV block handed to the parser (the rows of a block are converted together)."""


UNIT_ROUNDING = 1e-15
"""A quaternion norm this close to 1 is unit to rounding and is not renormalised."""


class RecordedDataError(ConfigError):
    """A recorded file that cannot be used (exit 2); the message names the file, row, column."""


@dataclass(frozen=True)
class ReadLimits:
    """What the reader accepts (``recorded`` of the config; :func:`~.grid.read_limits`)."""

    max_rows: int = 5_000_000  # more rows: refused while streaming (the epoch limit)
    quaternion_tolerance: float = 1e-6  # |‖q‖ − 1| above it: refused; within: renormalised
    max_rate_rad_s: float = 10.0  # a larger |ω|: refused ("deg/s given?")
    chunk_rows: int = 262_144  # Parquet rows per batch


@dataclass(frozen=True)
class RecordedTruth:
    """The truth columns of a file (SI)."""

    q: np.ndarray  # (n, 4) unit quaternions
    bias: np.ndarray  # (n, 3) rad/s
    calib: np.ndarray  # (n, 9)


@dataclass(frozen=True)
class RecordedRun:
    """One recorded file, checked (SI; absent ADS values are NaN rows)."""

    path: Path
    sha256: str
    t: np.ndarray  # (n,) s
    ads_q: np.ndarray  # (n, 4) renormalised; NaN rows where absent
    ads_rate: np.ndarray  # (n, 3) rad/s; NaN rows where absent
    gyro: np.ndarray  # (n, 3) rad/s
    truth: RecordedTruth | None

    @property
    def n_rows(self) -> int:
        return int(self.t.size)

    @property
    def has_truth(self) -> bool:
        return self.truth is not None

    @property
    def has_attitude(self) -> np.ndarray:
        return np.isfinite(self.ads_q[:, 0])

    @property
    def has_rate(self) -> np.ndarray:
        return np.isfinite(self.ads_rate[:, 0])


def data_files(paths: Sequence[str | Path]) -> list[Path]:
    """The files of ``paths``: files as given, folders expanded to their ``*.csv``,
    ``*.parquet`` and ``*.pq`` files (sorted by name)."""
    if not paths:
        raise RecordedDataError("no data file given")
    files: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in EXTENSIONS)
            if not found:
                raise RecordedDataError(f"{p}: a folder without .csv or .parquet files")
            files += found
        elif not p.exists():
            raise RecordedDataError(f"{p}: no such data file")
        elif p.suffix.lower() not in EXTENSIONS:
            raise RecordedDataError(f"{p}: not a .csv, .parquet or .pq file")
        else:
            files.append(p)
    seen: set[Path] = set()
    for f in files:
        if f.resolve() in seen:
            raise RecordedDataError(f"{f}: given twice")
        seen.add(f.resolve())
    return files


def sha256(path: Path) -> str:
    """SHA-256 of the file's bytes (streamed)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_header(path: Path, names: Sequence[str]) -> bool:
    """Refuse missing, unknown, duplicate or partial-truth columns; True if truth is present."""
    twice = sorted({c for c in names if list(names).count(c) > 1})
    if twice:
        raise RecordedDataError(f"{path}: column {', '.join(twice)} appears twice")
    unknown = [c for c in names if c not in ALL_COLUMNS]
    if unknown:
        raise RecordedDataError(
            f"{path}: unknown column {', '.join(repr(c) for c in unknown)}; the columns are "
            f"{', '.join(REQUIRED_COLUMNS)} and optionally all of {', '.join(TRUTH_COLUMNS)} "
            "(docs/recorded_data.md)"
        )
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise RecordedDataError(f"{path}: missing column {', '.join(missing)}")
    truth = [c for c in TRUTH_COLUMNS if c in names]
    if truth and len(truth) < len(TRUTH_COLUMNS):
        absent = [c for c in TRUTH_COLUMNS if c not in names]
        raise RecordedDataError(
            f"{path}: truth columns are all or none; missing {', '.join(absent)}"
        )
    return bool(truth)


def _first_bad_text(col: pa.Array) -> tuple[int, str]:
    """Index and text of the first cell of ``col`` (text) that is not a number."""
    for i, v in enumerate(col.to_pylist()):
        if v is None:
            continue
        try:
            float(v)
        except ValueError:
            return i, v
    return 0, "?"  # pragma: no cover - the cast failed, so a cell does not parse


def _to_float(path: Path, name: str, col: pa.Array, row0: int) -> tuple[np.ndarray, np.ndarray]:
    """Column ``col`` of a block as float64 (NaN where empty) and its empty mask."""
    if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
        stripped = pc.utf8_trim_whitespace(col)
        empty = pc.fill_null(pc.equal(stripped, ""), True)
        stripped = pc.if_else(empty, pa.scalar(None, col.type), stripped)
        try:
            num = pc.cast(stripped, pa.float64())
        except pa.ArrowInvalid:
            i, text = _first_bad_text(stripped)
            raise RecordedDataError(
                f"{where(path, row0 + i + 1)}, column {name}: {text!r} is not a number"
            ) from None
    elif pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
        num = pc.cast(col, pa.float64())
    else:
        raise RecordedDataError(f"{path}: column {name} holds {col.type}, not numbers")
    mask = np.asarray(num.is_null().to_numpy(zero_copy_only=False), dtype=bool)
    # nulls come out as NaN (fill_null first: to_numpy of a column with nulls may give objects)
    values = np.array(pc.fill_null(num, np.nan).to_numpy(zero_copy_only=False), dtype=float)
    bad = np.flatnonzero(~mask & ~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        raise RecordedDataError(
            f"{where(path, row0 + i + 1)}, column {name}: {float(values[i])!r} (NaN and inf are "
            "not data; leave an ADS cell empty where there is no measurement)"
        )
    return values, mask


class _Collector:
    """Checks each block of rows and keeps its values."""

    def __init__(self, path: Path, names: list[str], limits: ReadLimits) -> None:
        self.path = path
        self.names = names
        self.limits = limits
        self.rows = 0
        self.last_t: float | None = None
        self.parts: dict[str, list[np.ndarray]] = {c: [] for c in names}

    def add(self, batch: pa.RecordBatch) -> None:
        path, row0 = self.path, self.rows
        n = batch.num_rows
        if n == 0:
            return
        if row0 + n > self.limits.max_rows:
            raise RecordedDataError(
                f"{path}: more than {self.limits.max_rows:,} rows: over the epoch limit "
                "recorded.max_epochs (split the run, or raise the limit)"
            )
        vals: dict[str, np.ndarray] = {}
        empty: dict[str, np.ndarray] = {}
        for name in self.names:
            vals[name], empty[name] = _to_float(path, name, batch.column(name), row0)
        # cells that must not be empty: time, gyro, truth
        for name in self.names:
            if name in (*ADS_Q, *ADS_RATE):
                continue
            if empty[name].any():
                i = int(np.argmax(empty[name]))
                raise RecordedDataError(f"{where(path, row0 + i + 1)}, column {name}: empty")
        # the ADS groups: all empty or none
        for what, group in OPTIONAL_GROUPS.items():
            m = np.stack([empty[c] for c in group], axis=1)
            part = np.flatnonzero(m.any(axis=1) & ~m.all(axis=1))
            if part.size:
                i = int(part[0])
                gone = [c for c, e in zip(group, m[i], strict=True) if e]
                raise RecordedDataError(
                    f"{where(path, row0 + i + 1)}, column {', '.join(gone)}: {what} partly "
                    f"empty (leave all of {', '.join(group)} empty where there is none)"
                )
        self._check_time(vals[TIME], row0)
        for group in RATE_COLUMNS:
            w = np.stack([vals[c] for c in group], axis=1)
            norm = np.sqrt(np.sum(w * w, axis=1))
            big = np.flatnonzero(norm > self.limits.max_rate_rad_s)  # NaN (absent): False
            if big.size:
                i = int(big[0])
                raise RecordedDataError(
                    f"{where(path, row0 + i + 1)}, column {', '.join(group)}: |ω| = "
                    f"{norm[i]:.6g} rad/s, above {self.limits.max_rate_rad_s:g} rad/s: deg/s "
                    "given? (rates are rad/s)"
                )
        for group in QUATERNIONS:
            if group[0] not in vals:
                continue
            q = np.stack([vals[c] for c in group], axis=1)
            norm = np.sqrt(np.sum(q * q, axis=1))
            off = np.abs(norm - 1.0)
            bad = np.flatnonzero(off > self.limits.quaternion_tolerance)  # NaN: False
            if bad.size:
                i = int(bad[0])
                raise RecordedDataError(
                    f"{where(path, row0 + i + 1)}, column {', '.join(group)}: not a unit "
                    f"quaternion (norm {norm[i]:.10g}; at most "
                    f"{self.limits.quaternion_tolerance:g} off 1 is renormalised)"
                )
            # renormalised; a quaternion already unit to rounding (a few ulp) is left bit for
            # bit, so that a file written by qkf reads back exactly (round trip)
            fix = off > UNIT_ROUNDING
            q[fix] = q[fix] / norm[fix, None]
            for j, c in enumerate(group):
                vals[c] = q[:, j]
        for name in self.names:
            self.parts[name].append(vals[name])
        self.rows += n

    def _check_time(self, t: np.ndarray, row0: int) -> None:
        prev = np.concatenate([[self.last_t if self.last_t is not None else -np.inf], t[:-1]])
        bad = np.flatnonzero(~(t > prev))
        if bad.size:
            i = int(bad[0])
            raise RecordedDataError(
                f"{where(self.path, row0 + i + 1)}, column {TIME}: t = {float(t[i])!r} s after "
                f"t = {float(prev[i])!r} s; time must be strictly increasing"
            )
        self.last_t = float(t[-1])

    def column(self, name: str) -> np.ndarray:
        parts = self.parts[name]
        out = np.concatenate(parts) if len(parts) > 1 else parts[0]
        self.parts[name] = []  # release the blocks as the result is assembled
        return out

    def stack(self, names: Sequence[str]) -> np.ndarray:
        return np.stack([self.column(c) for c in names], axis=1)


def _csv_batches(path: Path) -> tuple[list[str], Iterator[pa.RecordBatch]]:
    with path.open("rb") as f:
        head = f.readline()
    names = [c.strip().strip('"') for c in head.decode("utf-8-sig").strip().split(",")]
    if names == [""]:
        names = []
    check_header(path, names)
    try:
        reader = pacsv.open_csv(
            path,
            read_options=pacsv.ReadOptions(block_size=BLOCK_BYTES, use_threads=False),
            convert_options=pacsv.ConvertOptions(
                column_types=dict.fromkeys(names, pa.string()),
                strings_can_be_null=False,
                quoted_strings_can_be_null=False,
            ),
        )
    except (pa.ArrowInvalid, OSError) as exc:
        raise RecordedDataError(f"{path}: not a readable CSV file ({exc})") from None

    def batches() -> Iterator[pa.RecordBatch]:
        while True:
            try:
                batch = reader.read_next_batch()
            except StopIteration:
                return
            except pa.ArrowInvalid as exc:  # a row with another number of cells, mostly
                raise RecordedDataError(f"{path}: {exc}") from None
            yield batch

    return names, batches()


def _parquet_batches(path: Path, chunk_rows: int) -> tuple[list[str], Iterator[pa.RecordBatch]]:
    try:
        pf = pq.ParquetFile(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise RecordedDataError(f"{path}: not a readable Parquet file ({exc})") from None
    names = list(pf.schema_arrow.names)
    check_header(path, names)
    return names, pf.iter_batches(batch_size=chunk_rows)


def read_recorded(path: str | Path, limits: ReadLimits | None = None) -> RecordedRun:
    """Read and check one recorded file (CSV or Parquet); :class:`RecordedDataError` names the
    file, row and column of the first bad input."""
    limits = ReadLimits() if limits is None else limits
    path = Path(path)
    if path.is_dir() or not path.exists():
        raise RecordedDataError(f"{path}: no such data file")
    kind = EXTENSIONS.get(path.suffix.lower())
    if kind is None:
        raise RecordedDataError(f"{path}: not a .csv, .parquet or .pq file")
    if path.stat().st_size == 0:
        raise RecordedDataError(f"{path}: empty file (a header row and one row per epoch)")
    names, batches = (
        _csv_batches(path) if kind == "csv" else _parquet_batches(path, limits.chunk_rows)
    )
    col = _Collector(path, names, limits)
    for batch in batches:
        col.add(batch)
    if col.rows == 0:
        raise RecordedDataError(f"{path}: empty file: a header but no rows")
    truth = None
    if TRUE_Q[0] in names:
        truth = RecordedTruth(
            q=col.stack(TRUE_Q), bias=col.stack(TRUE_BIAS), calib=col.stack(TRUE_P)
        )
    return RecordedRun(
        path=path,
        sha256=sha256(path),
        t=col.column(TIME),
        ads_q=col.stack(ADS_Q),
        ads_rate=col.stack(ADS_RATE),
        gyro=col.stack(GYRO),
        truth=truth,
    )
