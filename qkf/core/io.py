"""Safe output (docs/architecture.md, "Output files").

* Files are written atomically: a temporary file beside the target, fsync, then a rename over
  it, so an interrupted run never leaves a half-written file.
* A run's output directory holds one run: :func:`staged_directory` writes into a sibling
  temporary directory and swaps it in whole when the run has finished, so files of an earlier
  run never linger beside new ones, and a failed run leaves the old directory untouched.
* Files and directories get the permissions the user's umask asks for (0644 / 0755 under the
  usual 022), not the 0600 of ``mkstemp``.
* :func:`check_output_dir` and :func:`check_output_file` refuse an unusable ``--out`` before
  any computation.
"""

from __future__ import annotations

import csv
import io
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any


class OutputError(OSError):
    """An output path that cannot be used; the message names it and says why."""


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Permissions of a new file under the current umask (0644 under 022)."""
    return 0o666 & ~_umask()


def dir_mode() -> int:
    """Permissions of a new directory under the current umask (0755 under 022)."""
    return 0o777 & ~_umask()


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
            os.fchmod(f.fileno(), file_mode())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def _check_parent(path: Path) -> Path:
    """Refuse a path whose nearest existing ancestor is not a writable directory."""
    base = path.parent.absolute()
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise OutputError(f"{path}: {base} is not a directory")
    if not os.access(base, os.W_OK | os.X_OK):
        raise OutputError(f"{path}: no permission to write in {base}")
    return path


def check_output_dir(path: str | Path) -> Path:
    """Refuse an output directory that cannot be created or replaced, before any work."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: exists and is not a directory")
    return _check_parent(path)


def check_output_file(path: str | Path) -> Path:
    """Refuse an output file path that cannot be written, before any work."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory, not a file")
    if path.exists() and not os.access(path, os.W_OK):
        raise OutputError(f"{path}: no permission to overwrite")
    return _check_parent(path)


@contextmanager
def staged_directory(path: str | Path) -> Iterator[Path]:
    """Write a run into a sibling temporary directory; on success it replaces ``path`` whole.

    Yields the staging directory. If the block raises, the staging directory is removed and
    ``path`` is left as it was. The swap is two renames (old aside, new in) followed by the
    removal of the old directory, so at no moment does ``path`` hold a mixture of two runs.
    """
    path = check_output_dir(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".staging", dir=path.parent))
    try:
        yield stage
        os.chmod(stage, dir_mode())
        old = None
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.replace(path, old / path.name)
        os.replace(stage, path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise


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
