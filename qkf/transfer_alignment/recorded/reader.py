"""Reading a recorded run, streamed in batches of rows, every bad input refused with the file,
row and column named (docs/recorded_data.md, "Bad input").

CSV is read with pyarrow's streaming reader (``pyarrow.csv.open_csv``) in batches of at most
``ReadLimits.chunk_rows`` rows and 1 MiB of text (:data:`MAX_BLOCK_BYTES`); Parquet with
``ParquetFile.iter_batches``, one row group at a time, in batches of ``chunk_rows`` rows. Each
batch is converted straight into the result arrays (allocated for the file's row count, or a
CSV estimate of it, and grown if short), so reading holds the result plus a batch (and
pyarrow's read-ahead, some 32 CSV blocks or one Parquet row group).

A CSV file is first read the fast way, every column parsed as float64 by pyarrow (an empty cell
is null). pyarrow's conversion errors do not say where the bad cell is, so when a batch fails
to convert the file is read again as text, every column cast by ``pyarrow.compute`` (a failed
cast is bisected to its first bad cell): that read names the row and column, or, if the failure
was only a cell of blanks (an empty cell), gives the data. Every check runs on each batch as it
arrives, so a file over the row limit is refused without being read to its end, and the first
bad row of the file is the one named (several problems in one row: the first check's).

Rows are numbered from 1 after the header. Messages say ``FILE: row R (line L), column C: …``
for CSV (the line counts the header and any blank line, which the parser skips) and
``FILE: row R, column C: …`` for Parquet.
"""

from __future__ import annotations

import csv
import hashlib
import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from qkf.core.config import ConfigError
from qkf.core.csvfile import DataFileError, check_path
from qkf.transfer_alignment.recorded.columns import (
    ALL_COLUMNS,
    EXTENSIONS,
    GROUPS,
    NEVER_EMPTY,
    OPTIONAL_GROUPS,
    QUATERNIONS,
    RATE_COLUMNS,
    REQUIRED_COLUMNS,
    TIME,
    TRUTH_COLUMNS,
)

UNIT_ROUNDING = 1e-15
"""A quaternion whose norm is this close to 1 is unit to rounding (a few ulp) and is kept bit
for bit: dividing by such a norm would only move the last bits (so a file written by qkf reads
back exactly)."""
MIN_BLOCK_BYTES = 1 << 14
MAX_BLOCK_BYTES = 1 << 20
"""Bounds of the CSV parser's block (bytes), which sets the rows per batch: ``chunk_rows`` rows
of the file's typical length, but at most 1 MiB of text (about 2,100 rows with truth).
pyarrow's streaming reader reads some 32 blocks ahead of the batch handed over, so the block
bounds the memory in flight (about 37 MiB at 1 MiB; 400 MiB at 16 MiB). Reading is no
faster with larger blocks (a day at 10 Hz with truth: 1.6 to 2.0 s with 1 to 16 MiB)."""
_SAMPLE_BYTES = 1 << 20
"""The start of a CSV file read for its header and the typical row length."""


class RecordedDataError(ConfigError):
    """A recorded file that cannot be used (exit 2); the message names the file, row, column."""


@dataclass(frozen=True)
class ReadLimits:
    """What the reader accepts (``recorded`` of the config; :func:`~.grid.read_limits`)."""

    max_rows: int = 5_000_000  # more rows: refused while streaming (the epoch limit)
    quaternion_tolerance: float = 1e-6  # |‖q‖ − 1| above it: refused; within: renormalised
    max_rate_rad_s: float = 10.0  # a larger |ω| (ADS rate or gyro): refused ("deg/s given?")
    chunk_rows: int = 262_144  # rows per streamed batch (CSV: at most, about)
    ignore_columns: frozenset[str] = frozenset()  # extra columns read past (never used)

    def __post_init__(self) -> None:
        if self.max_rows < 1 or self.chunk_rows < 1:
            raise ValueError("ReadLimits: max_rows and chunk_rows must be at least 1")
        if not (self.quaternion_tolerance >= 0.0 and self.max_rate_rad_s > 0.0):
            raise ValueError("ReadLimits: quaternion_tolerance must be ≥ 0 and max_rate_rad_s > 0")


@dataclass(frozen=True)
class RecordedTruth:
    """The truth columns of a file (SI)."""

    q: np.ndarray  # (n, 4) unit quaternions, scalar-last
    bias: np.ndarray  # (n, 3) rad/s
    calib: np.ndarray  # (n, 9) dimensionless, calibration order


@dataclass(frozen=True)
class RecordedRun:
    """One recorded file, checked (SI; absent ADS values are NaN rows)."""

    path: Path
    sha256: str  # of the file's bytes
    t: np.ndarray  # (n,) s, strictly increasing
    ads_q: np.ndarray  # (n, 4) unit (renormalised); NaN rows where absent
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
        """(n,) bool: the row has an ADS attitude."""
        return np.isfinite(self.ads_q[:, 0])

    @property
    def has_rate(self) -> np.ndarray:
        """(n,) bool: the row has an ADS rate."""
        return np.isfinite(self.ads_rate[:, 0])


def data_files(paths: Sequence[str | Path]) -> list[Path]:
    """The files of ``paths``: files as given, folders expanded to their ``*.csv``,
    ``*.parquet`` and ``*.pq`` files (sorted by name). A missing path, a folder without such
    files, another extension and a file given twice are refused (:class:`RecordedDataError`)."""
    if not paths:
        raise RecordedDataError("no data file given")
    files: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = sorted(
                (f for f in p.iterdir() if f.is_file() and f.suffix.lower() in EXTENSIONS),
                key=lambda f: f.name,
            )
            if not found:
                raise RecordedDataError(f"{p}: a folder without .csv, .parquet or .pq files")
            files += found
        elif not p.exists():
            raise RecordedDataError(f"{p}: no such data file")
        elif not p.is_file():
            raise RecordedDataError(f"{p}: not a regular file")
        elif p.suffix.lower() not in EXTENSIONS:
            raise RecordedDataError(f"{p}: not a .csv, .parquet or .pq file")
        else:
            files.append(p)
    seen: dict[Path, Path] = {}
    for f in files:
        key = f.resolve()
        if key in seen:
            same = "" if seen[key] == f else f" (as {seen[key]})"
            raise RecordedDataError(f"{f}: given twice{same}")
        seen[key] = f
    return files


def sha256(path: Path) -> str:
    """SHA-256 of the file's bytes (streamed)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_header(
    path: Path, names: Sequence[str], ignore: frozenset[str] = frozenset()
) -> list[str]:
    """Refuse duplicate, unknown, missing or partial-truth columns; the columns to read (every
    column but those in ``ignore``, which may not be a column qkf reads)."""
    twice = sorted({c for c in names if list(names).count(c) > 1})
    if twice:
        raise RecordedDataError(
            f"{path}: column {', '.join(repr(c) for c in twice)} appears more than once"
        )
    used = sorted(ignore & set(ALL_COLUMNS))
    if used:
        raise RecordedDataError(
            f"{path}: column {', '.join(repr(c) for c in used)} is read by qkf and cannot be "
            "ignored (--ignore-column / recorded.ignore_columns is for extra columns)"
        )
    unknown = [c for c in names if c not in ALL_COLUMNS and c not in ignore]
    if unknown:
        raise RecordedDataError(
            f"{path}: unknown column {', '.join(repr(c) for c in unknown)}; the columns are "
            f"{', '.join(REQUIRED_COLUMNS)} and optionally all of {', '.join(TRUTH_COLUMNS)} "
            "(docs/recorded_data.md). Extra columns can be read past: --ignore-column NAME "
            "(config: recorded.ignore_columns)"
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
    return [c for c in names if c not in ignore]


def line_of(path: Path, row: int) -> int:
    """The line of CSV data row ``row`` (1-based; the header is line 1): the parser skips blank
    lines, so they are counted here (only for a message: the file is read up to the row)."""
    seen = 0
    with path.open("rb") as f:
        for line, raw in enumerate(f, start=1):
            if raw in (b"\n", b"\r\n"):
                continue
            if seen == row:
                return line
            seen += 1
    return row + 1  # lines ended by a lone CR (not split here)


def _over_limit(path: Path, limits: ReadLimits) -> RecordedDataError:
    return RecordedDataError(
        f"{path}: more than {limits.max_rows:,} rows: over the epoch limit of "
        f"{limits.max_rows:,} (recorded.max_epochs; split the run, or raise the limit)"
    )


@dataclass
class _Column:
    """One column of a batch as float64."""

    values: np.ndarray  # NaN where empty (and after a cell that is not a number)
    empty: np.ndarray | None  # True where the cell is empty; None: none is
    bad: tuple[int, str] | None = None  # the first cell that is not a number: index, text


def _first_failing_cast(text: pa.Array) -> int:
    """Index of the first cell of ``text`` that does not cast to float64 (the whole does not):
    bisection on prefixes, so the parser's own notion of a number decides."""
    lo, hi = 0, len(text)  # the first lo cells cast; the first hi do not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            pc.cast(text.slice(0, mid), pa.float64())
            lo = mid
        except pa.ArrowInvalid:
            hi = mid
    return hi - 1


def _from_text(col: pa.Array) -> _Column:
    """A text column: blanks trimmed, an empty cell null, the rest cast to float64."""
    text = pc.utf8_trim_whitespace(col)
    is_empty = pc.fill_null(pc.equal(text, ""), True)
    text = pc.if_else(is_empty, pa.scalar(None, text.type), text)
    empty = np.asarray(is_empty.to_numpy(zero_copy_only=False), dtype=bool)
    bad = None
    try:
        num = pc.cast(text, pa.float64())
    except pa.ArrowInvalid:
        i = _first_failing_cast(text)
        bad = (i, str(text[i].as_py()))
        head = pc.cast(text.slice(0, i), pa.float64())
        num = pa.concat_arrays([head, pa.nulls(len(text) - i, pa.float64())])
    values = np.asarray(num.to_numpy(zero_copy_only=False), dtype=np.float64)
    return _Column(values, empty if empty.any() else None, bad)


def _to_column(path: Path, name: str, col: pa.Array) -> _Column:
    """A column of a batch as float64 (numbers, text or all-null)."""
    typ = col.type
    if pa.types.is_string(typ) or pa.types.is_large_string(typ):
        return _from_text(col)
    if pa.types.is_null(typ):
        return _Column(np.full(len(col), np.nan), np.ones(len(col), dtype=bool))
    if pa.types.is_floating(typ) or pa.types.is_integer(typ) or pa.types.is_decimal(typ):
        num = col if typ == pa.float64() else pc.cast(col, pa.float64())
        # a float array's nulls come out as NaN
        values = np.asarray(num.to_numpy(zero_copy_only=False), dtype=np.float64)
        empty = None
        if num.null_count:
            empty = np.asarray(num.is_null().to_numpy(zero_copy_only=False), dtype=bool)
        return _Column(values, empty)
    raise RecordedDataError(f"{path}: column {name} holds {typ}, not numbers")


def _first(mask: np.ndarray) -> int | None:
    """Index of the first True row of ``mask`` ((n,) or (n, k): any in the row), or None."""
    rows = np.asarray(mask if mask.ndim == 1 else mask.any(axis=1), dtype=bool)
    if not rows.size:
        return None
    i = int(np.argmax(rows))
    return i if rows[i] else None


def _at_first(mask: np.ndarray, message: Callable[[int], str]) -> list[tuple[int, str]]:
    """``[(i, message(i))]`` for the first True row ``i`` of ``mask``; empty if there is none."""
    i = _first(mask)
    return [] if i is None else [(i, message(i))]


def _cell_problems(
    names: tuple[str, ...], block: np.ndarray, empty: np.ndarray
) -> list[tuple[int, str]]:
    """The first cell of a group that is not finite, the first empty one where none may be,
    the first row with an optional group partly empty: ``(index, "column …: what")``."""
    out: list[tuple[int, str]] = []
    optional = names in OPTIONAL_GROUPS.values()
    i = _first(~np.isfinite(block) & ~empty)
    if i is not None:
        j = int(np.argmax(~np.isfinite(block[i]) & ~empty[i]))
        hint = " (leave all its cells empty at an epoch without one)" if optional else ""
        out.append((i, f"{names[j]}: {float(block[i, j])!r} is not a finite number{hint}"))
    if names[0] in NEVER_EMPTY:
        i = _first(empty)
        if i is not None:
            j = int(np.argmax(empty[i]))
            out.append((i, f"{names[j]}: empty (every row needs a number here)"))
    else:
        i = _first(np.any(empty, axis=1) & ~np.all(empty, axis=1))
        if i is not None:
            gone = [c for c, e in zip(names, empty[i], strict=True) if e]
            what = next(w for w, g in OPTIONAL_GROUPS.items() if g == names)
            out.append(
                (
                    i,
                    f"{', '.join(gone)}: {what} partly empty (leave all of {', '.join(names)} "
                    "empty where there is none)",
                )
            )
    return out


class _Collector:
    """Checks each batch of rows and keeps its values, group by group, in arrays that grow.

    Each group's array is allocated for ``capacity`` rows (Parquet: the file's row count;
    CSV: an estimate from the file's size) and grows by half when a batch does not fit; a
    batch is converted straight into it, so nothing is held beside the arrays but the batch.
    """

    def __init__(
        self, path: Path, names: Sequence[str], limits: ReadLimits, csv: bool, capacity: int
    ) -> None:
        self.path = path
        self.names = list(names)
        self.limits = limits
        self.csv = csv
        self.groups = {g: cols for g, cols in GROUPS.items() if cols[0] in self.names}
        self.rows = 0
        self.last_t = -np.inf
        capacity = max(1, min(capacity, limits.max_rows))
        self.arrays = {g: np.empty((capacity, len(cols))) for g, cols in self.groups.items()}

    def _room(self, n: int) -> None:
        """Grow the arrays to hold ``n`` more rows."""
        have = next(iter(self.arrays.values())).shape[0]
        if self.rows + n <= have:
            return
        size = min(max(self.rows + n, have + have // 2), self.limits.max_rows)
        for g, old in self.arrays.items():
            new = np.empty((size, old.shape[1]))
            new[: self.rows] = old[: self.rows]
            self.arrays[g] = new

    def where(self, row: int) -> str:
        """``FILE: row R (line L)`` (CSV) or ``FILE: row R`` (Parquet); ``row`` 1-based."""
        if self.csv:
            return f"{self.path}: row {row} (line {line_of(self.path, row)})"
        return f"{self.path}: row {row}"

    def add(self, batch: pa.RecordBatch) -> None:
        n = batch.num_rows
        if n == 0:
            return
        if self.rows + n > self.limits.max_rows:
            raise _over_limit(self.path, self.limits)
        cols = {
            name: _to_column(self.path, name, batch.column(j))
            for j, name in enumerate(batch.schema.names)
        }
        self._room(n)
        blocks: dict[str, np.ndarray] = {}  # this batch's rows of the arrays (views)
        empties: dict[str, np.ndarray] = {}
        for g, names in self.groups.items():
            blocks[g] = self.arrays[g][self.rows : self.rows + n]
            empties[g] = np.zeros((n, len(names)), dtype=bool)
            for j, c in enumerate(names):
                blocks[g][:, j] = cols[c].values
                e = cols[c].empty
                if e is not None:
                    empties[g][:, j] = e
        # each check's first violation: (index in the batch, "column …: what"); the earliest
        # row is reported, ties in the order of the checks. A cell that is not a number comes
        # first: the NaN it leaves behind trips later checks at its row or after, never before.
        found: list[tuple[int, str]] = []
        for c in self.names:
            bad = cols[c].bad
            if bad is not None:
                found.append((bad[0], f"{c}: {bad[1]!r} is not a number"))
        for g, names in self.groups.items():
            found += _cell_problems(names, blocks[g], empties[g])
        found += self._time(blocks["t"][:, 0])
        norms: dict[str, np.ndarray] = {}
        for g, names in self.groups.items():
            if names in RATE_COLUMNS:
                found += self._rate(names, blocks[g])
            if names in QUATERNIONS:
                norms[g] = np.sqrt(np.einsum("ij,ij->i", blocks[g], blocks[g]))
                found += self._quaternion(names, norms[g])
        if found:
            i, message = min(found, key=lambda f: f[0])
            raise RecordedDataError(f"{self.where(self.rows + i + 1)}, column {message}")
        for g, norm in norms.items():
            # renormalised; unit to rounding already: kept bit for bit (UNIT_ROUNDING)
            fix = np.abs(norm - 1.0) > UNIT_ROUNDING  # NaN (absent): False
            if fix.any():
                blocks[g][fix] /= norm[fix, None]
        self.rows += n
        self.last_t = float(blocks["t"][-1, 0])

    def _time(self, t: np.ndarray) -> list[tuple[int, str]]:
        prev = np.concatenate([[self.last_t], t[:-1]])
        return _at_first(
            ~(t > prev),
            lambda i: (
                f"{TIME}: t = {float(t[i])!r} s after t = {float(prev[i])!r} s in row "
                f"{self.rows + i}; time must be strictly increasing"
            ),
        )

    def _rate(self, names: tuple[str, ...], w: np.ndarray) -> list[tuple[int, str]]:
        norm = np.sqrt(np.einsum("ij,ij->i", w, w))
        return _at_first(
            norm > self.limits.max_rate_rad_s,  # NaN (absent): False
            lambda i: (
                f"{', '.join(names)}: |ω| = {float(norm[i]):.6g} rad/s, above "
                f"{self.limits.max_rate_rad_s:g} rad/s: deg/s given? (rates are rad/s)"
            ),
        )

    def _quaternion(self, names: tuple[str, ...], norm: np.ndarray) -> list[tuple[int, str]]:
        return _at_first(
            np.abs(norm - 1.0) > self.limits.quaternion_tolerance,  # NaN: False
            lambda i: (
                f"{', '.join(names)}: not a unit quaternion (norm {float(norm[i])!r}; at "
                f"most {self.limits.quaternion_tolerance:g} off 1 is renormalised)"
            ),
        )

    def array(self, group: str) -> np.ndarray:
        """The rows of one group, (n, k): a view of its array, or a copy if the array is over
        a quarter too long (an estimate far off)."""
        a = self.arrays.pop(group)
        return a[: self.rows] if a.shape[0] - self.rows <= self.rows // 4 else a[: self.rows].copy()


def _csv_header(path: Path, limits: ReadLimits) -> tuple[list[str], list[str], int, int]:
    """The column names of a CSV file, those read (not ignored), the parser's block size
    (bytes) for batches of about ``limits.chunk_rows`` rows, and an estimate of its rows, from
    the start of the file."""
    with path.open("rb") as f:
        sample = f.read(_SAMPLE_BYTES)
    if not sample.strip():
        raise RecordedDataError(f"{path}: empty file (a header row, then one row per epoch)")
    end = sample.find(b"\n")
    if end < 0 and len(sample) == _SAMPLE_BYTES:
        raise RecordedDataError(f"{path}: line 1 is over {_SAMPLE_BYTES:,} bytes: not a header")
    head = sample if end < 0 else sample[:end]
    try:
        text = head.decode("utf-8-sig").rstrip("\r")
    except UnicodeDecodeError:
        raise RecordedDataError(f"{path}: line 1: not UTF-8 text (a CSV header)") from None
    if not text.strip():
        raise RecordedDataError(
            f"{path}: line 1 is blank; the first line is the header ({', '.join(REQUIRED_COLUMNS)})"
        )
    names = [c.strip() for c in next(csv.reader([text]))]
    _refuse_other_separator(path, names)
    kept = check_header(path, names, limits.ignore_columns)
    body = b"" if end < 0 else sample[end + 1 :]
    lines = body.count(b"\n")
    row_bytes = len(body) / lines if lines else len(head) + 1.0
    longest = max((len(r) for r in body.split(b"\n")), default=0) + 1
    block = int(
        min(max(limits.chunk_rows * row_bytes, 4 * longest, MIN_BLOCK_BYTES), MAX_BLOCK_BYTES)
    )
    rows = int(path.stat().st_size / row_bytes * 1.02) + 16
    return names, kept, block, rows


def _refuse_other_separator(path: Path, names: list[str]) -> None:
    """A header that is one cell holding the column names joined by ``;`` or a tab: a
    spreadsheet's export for a locale with decimal commas (refused with that hint)."""
    if len(names) != 1:
        return
    for sep, what in ((";", "';'"), ("\t", "tabs")):
        cells = [c.strip() for c in names[0].split(sep)]
        if len(cells) > 1 and TIME in cells:
            raise RecordedDataError(
                f"{path}: line 1: the columns are separated by {what}; qkf reads comma-separated "
                "files with decimal points (a spreadsheet's export for a decimal-comma locale? "
                "save as CSV with ',' between cells and '.' in numbers)"
            )


class _SlowRead(Exception):
    """A batch failed to convert to numbers: read the file again as text."""


def _csv_batches(
    path: Path, names: list[str], kept: list[str], block: int, fast: bool
) -> Iterator[pa.RecordBatch]:
    """The file's batches: numbers (``fast``: raises :class:`_SlowRead` on the first one that
    does not convert) or text (one thread, so a row of the wrong length is numbered)."""
    invalid: list[pacsv.InvalidRow] = []

    def on_invalid(row: pacsv.InvalidRow) -> str:
        invalid.append(row)
        return "error"

    read = pacsv.ReadOptions(block_size=block, use_threads=False, column_names=names, skip_rows=1)
    if fast:
        parse = pacsv.ParseOptions()
        convert = pacsv.ConvertOptions(
            column_types=dict.fromkeys(kept, pa.float64()),
            null_values=[""],
            include_columns=kept,
        )
    else:
        parse = pacsv.ParseOptions(invalid_row_handler=on_invalid)
        convert = pacsv.ConvertOptions(
            column_types=dict.fromkeys(kept, pa.string()),
            strings_can_be_null=False,
            quoted_strings_can_be_null=False,
            include_columns=kept,
        )
    try:
        reader = pacsv.open_csv(
            path, read_options=read, parse_options=parse, convert_options=convert
        )
        while True:
            try:
                batch = reader.read_next_batch()
            except StopIteration:
                return
            yield batch
    except pa.ArrowInvalid as exc:
        if fast:
            raise _SlowRead from exc
        if invalid and invalid[0].number is not None:
            bad = invalid[0]
            row = bad.number - 1  # the parser counts the header as row 1
            cells = f"{bad.actual_columns} cell{'s' if bad.actual_columns != 1 else ''}"
            hint = (
                "; decimal commas? numbers take '.', and ',' separates the cells"
                if bad.actual_columns > bad.expected_columns and re.search(r"\d,\d", bad.text)
                else ""
            )
            raise RecordedDataError(
                f"{path}: row {row} (line {line_of(path, row)}): {cells}, the header has "
                f"{bad.expected_columns} ({bad.text[:60]!r}){hint}"
            ) from None
        # the parser's own message, e.g. text that is not UTF-8: its row and column named
        found = re.match(r"In CSV column #(\d+): Row #(\d+): (.*)", str(exc), re.DOTALL)
        if found and int(found[1]) < len(names) and int(found[2]) > 1:
            row = int(found[2]) - 1
            raise RecordedDataError(
                f"{path}: row {row} (line {line_of(path, row)}), column {names[int(found[1])]}: "
                f"{found[3]}"
            ) from None
        raise RecordedDataError(f"{path}: not a readable CSV file ({exc})") from None
    except OSError as exc:
        raise RecordedDataError(f"{path}: cannot be read ({exc})") from None


def _read_csv(path: Path, limits: ReadLimits) -> _Collector:
    names, kept, block, rows = _csv_header(path, limits)
    col = _Collector(path, kept, limits, csv=True, capacity=rows)
    try:
        for batch in _csv_batches(path, names, kept, block, fast=True):
            col.add(batch)
        return col
    except _SlowRead:
        del col
    col = _Collector(path, kept, limits, csv=True, capacity=rows)
    for batch in _csv_batches(path, names, kept, block, fast=False):
        col.add(batch)
    return col


def _read_parquet(path: Path, limits: ReadLimits) -> _Collector:
    try:
        pf = pq.ParquetFile(path, pre_buffer=False)  # pre-buffering reads all row groups
    except (pa.ArrowInvalid, OSError) as exc:
        raise RecordedDataError(f"{path}: not a readable Parquet file ({exc})") from None
    names = check_header(path, list(pf.schema_arrow.names), limits.ignore_columns)
    if pf.metadata.num_rows > limits.max_rows:  # from the footer: nothing read
        raise _over_limit(path, limits)
    col = _Collector(path, names, limits, csv=False, capacity=pf.metadata.num_rows)
    try:
        for group in range(pf.metadata.num_row_groups):  # one row group decoded at a time
            for batch in pf.iter_batches(
                batch_size=limits.chunk_rows, row_groups=[group], columns=names
            ):
                col.add(batch)
    except (pa.ArrowInvalid, OSError) as exc:
        raise RecordedDataError(f"{path}: not a readable Parquet file ({exc})") from None
    return col


def read_recorded(path: str | Path, limits: ReadLimits | None = None) -> RecordedRun:
    """Read and check one recorded file (CSV or Parquet); :class:`RecordedDataError` names the
    file, and the row and column of the first bad input."""
    limits = ReadLimits() if limits is None else limits
    try:
        path = check_path(path)  # every problem's data files are refused alike
    except DataFileError as exc:
        raise RecordedDataError(str(exc)) from None
    kind = EXTENSIONS.get(path.suffix.lower())
    if kind is None:
        raise RecordedDataError(f"{path}: not a .csv, .parquet or .pq file")
    if path.stat().st_size == 0:
        raise RecordedDataError(
            f"{path}: empty file (0 bytes; a header row, then one row per epoch)"
        )
    col = _read_csv(path, limits) if kind == "csv" else _read_parquet(path, limits)
    if col.rows == 0:
        raise RecordedDataError(f"{path}: empty file: a header but no rows")
    truth = None
    if "true_q" in col.groups:
        truth = RecordedTruth(
            q=col.array("true_q"), bias=col.array("true_bias"), calib=col.array("true_p")
        )
    return RecordedRun(
        path=path,
        sha256=sha256(path),
        t=col.array("t")[:, 0],
        ads_q=col.array("ads_q"),
        ads_rate=col.array("ads_rate"),
        gyro=col.array("gyro"),
        truth=truth,
    )
