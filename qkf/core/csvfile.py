"""Reading the named columns of a user's CSV file, with errors that name the file, row and column.

Every problem that accepts recorded data (``qkf fuse --sca/--acc``, ``qkf align --data``,
``qkf gyros run --data``) opens it through :func:`read_table`: a header row, then data rows;
blank lines are skipped, a UTF-8 byte-order mark (as spreadsheets write) is dropped. The
columns a reader needs are located by :func:`find_columns`, which refuses a missing column and
a needed column that appears twice (which of the two is meant would be a guess); other columns
are ignored, duplicated or not. :func:`read_records` does both and also refuses rows whose field
count differs from the header's. Rows are numbered from 1 after the header (the file line is the
row + 1), and messages say both: ``FILE: row 3 (line 4), column t_s: …``.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path


class DataFileError(ValueError):
    """A data file that cannot be used; the message names the file, row and column."""


def where(path: str | Path, row: int) -> str:
    """``FILE: row R (line R+1)``, the prefix of every message about one row."""
    return f"{path}: row {row} (line {row + 1})"


def check_path(path: str | Path) -> Path:
    """``path`` as a :class:`Path` if it names a regular file; a directory, a missing path or
    something else (a FIFO, a device) is refused, each with its own message."""
    p = Path(path)
    if p.is_dir():
        raise DataFileError(f"{p}: is a directory, not a data file")
    if not p.exists():
        raise DataFileError(f"{p}: no such data file")
    if not p.is_file():
        raise DataFileError(f"{p}: not a regular file")
    return p


def read_table(
    path: str | Path, columns: Sequence[str]
) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The header (names stripped) and the non-blank data rows ``(row number, fields)`` of a
    CSV file; ``columns`` (the ones the caller needs) only shape the empty-file message.

    Raises :class:`DataFileError` for a path that is not a readable regular file, a file that
    is not UTF-8 text or not CSV, and a file without a header.
    """
    p = check_path(path)
    try:
        # utf-8-sig: a leading byte-order mark would otherwise glue itself to the first name
        with p.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header is None:
                raise DataFileError(f"{p}: empty file (expected a header: {', '.join(columns)})")
            records = [
                (k, rec)
                for k, rec in enumerate(reader, start=1)
                if rec and any(x.strip() for x in rec)
            ]
    except UnicodeDecodeError as exc:
        raise DataFileError(f"{p}: not a text file (UTF-8): {exc.reason}") from None
    except csv.Error as exc:
        raise DataFileError(f"{p}: not a CSV file: {exc}") from None
    except OSError as exc:  # permissions, a file removed meanwhile: still the user's input
        raise DataFileError(f"{p}: cannot be read: {exc.strerror or exc}") from None
    return [h.strip() for h in header], records


def refuse_duplicates(path: str | Path, header: Sequence[str], columns: Sequence[str]) -> None:
    """Refuse a needed column that the header names more than once (1-based field numbers in
    the message); duplicates among the ignored columns are harmless and pass."""
    for c in columns:
        fields = [i + 1 for i, h in enumerate(header) if h == c]
        if len(fields) > 1:
            shown = ", ".join(map(str, fields[:-1])) + f" and {fields[-1]}"
            times = "twice" if len(fields) == 2 else f"{len(fields)} times"
            raise DataFileError(
                f"{path}: line 1: column {c} appears {times} in the header (fields {shown}); "
                "keep one"
            )


def find_columns(path: str | Path, header: Sequence[str], columns: Sequence[str]) -> list[int]:
    """The field index of each of ``columns`` in ``header``; refuses a missing column and a
    needed column that appears twice."""
    missing = [c for c in columns if c not in header]
    if missing:
        raise DataFileError(
            f"{path}: missing column {', '.join(missing)} (header: {', '.join(header)}; "
            f"expected {', '.join(columns)})"
        )
    refuse_duplicates(path, header, columns)
    return [list(header).index(c) for c in columns]


def read_records(path: str | Path, columns: tuple[str, ...]) -> list[tuple[int, list[str]]]:
    """The data rows of a CSV file as ``(row number, [the named columns' text, stripped])``.

    Raises :class:`DataFileError` for a path that is not a readable file (a directory, a missing
    file), a missing or duplicated column, a row whose field count differs from the header's, or
    a file without data rows.
    """
    p = Path(path)
    names, table = read_table(p, columns)
    idx = find_columns(p, names, columns)
    records: list[tuple[int, list[str]]] = []
    for k, rec in table:
        if len(rec) != len(names):
            raise DataFileError(f"{where(p, k)}: {len(rec)} fields, the header has {len(names)}")
        records.append((k, [rec[i].strip() for i in idx]))
    if not records:
        raise DataFileError(f"{p}: no data rows")
    return records
