"""Atomic file output: everything is written to a temporary file beside the target, then
renamed over it, so an interrupted run never leaves a half-written result."""

from __future__ import annotations

import csv
import io
import os
import re
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (same-directory temp file, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def slug(value: object) -> str:
    """A file-name-safe rendering of a value: runs of other characters become ``_``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(value))


def format_value(v: Any) -> str:
    """Numbers with full round-trip precision, so a rerun with the same seed is byte-identical."""
    if isinstance(v, float):
        return repr(v)
    return str(v)


def csv_text(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow([format_value(v) for v in row])
    return buf.getvalue()


def atomic_write_csv(
    path: str | Path, header: Sequence[str], rows: Iterable[Sequence[Any]]
) -> None:
    atomic_write_text(path, csv_text(header, rows))
