"""Reading the named columns of a user's CSV file, with errors that name the file, row and column.

Every problem that accepts recorded data (``qkf fuse --sca/--acc``, ``qkf align --data``) reads it
through :func:`read_records`: a header row, then data rows; other columns are ignored, blank lines
skipped. Rows are numbered from 1 after the header (the file line is the row + 1), and messages
say both: ``FILE: row 3 (line 4), column t_s: …``.
"""

from __future__ import annotations

import csv
from pathlib import Path


class DataFileError(ValueError):
    """A data file that cannot be used; the message names the file, row and column."""


def where(path: str | Path, row: int) -> str:
    """``FILE: row R (line R+1)``, the prefix of every message about one row."""
    return f"{path}: row {row} (line {row + 1})"


def read_records(path: str | Path, columns: tuple[str, ...]) -> list[tuple[int, list[str]]]:
    """The data rows of a CSV file as ``(row number, [the named columns' text, stripped])``.

    Raises :class:`DataFileError` for a missing or unreadable file, a missing column, a row whose
    field count differs from the header's, or a file without data rows.
    """
    p = Path(path)
    if p.is_dir():
        raise DataFileError(f"{p}: is a directory, not a data file")
    if not p.is_file():
        raise DataFileError(f"{p}: no such data file")
    records: list[tuple[int, list[str]]] = []
    try:
        with p.open(newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header is None:
                raise DataFileError(f"{p}: empty file (expected a header: {', '.join(columns)})")
            names = [h.strip() for h in header]
            missing = [c for c in columns if c not in names]
            if missing:
                raise DataFileError(
                    f"{p}: missing column {', '.join(missing)} (header: {', '.join(names)}; "
                    f"expected {', '.join(columns)})"
                )
            idx = [names.index(c) for c in columns]
            for k, rec in enumerate(reader, start=1):
                if not rec or all(not x.strip() for x in rec):
                    continue
                if len(rec) != len(names):
                    raise DataFileError(
                        f"{where(p, k)}: {len(rec)} fields, the header has {len(names)}"
                    )
                records.append((k, [rec[i].strip() for i in idx]))
    except UnicodeDecodeError as exc:
        raise DataFileError(f"{p}: not a text file (UTF-8): {exc.reason}") from None
    except csv.Error as exc:
        raise DataFileError(f"{p}: not a CSV file: {exc}") from None
    if not records:
        raise DataFileError(f"{p}: no data rows")
    return records
