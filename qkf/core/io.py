"""Safe output (docs/architecture.md, "Output files").

* Files are written atomically: a temporary file beside the target, fsync, then a rename over
  it, so an interrupted run never leaves a half-written file.
* A run's output directory holds one run: :func:`staged_directory` writes into a sibling
  temporary directory and swaps it in whole when the run has finished, so files of an earlier
  run never linger beside new ones, and a failed run leaves the old directory untouched.
* Never delete what qkf did not write: a folder is replaced only when it is empty or holds
  nothing but an earlier run of the same kind, recognised by its ``run.json`` (whose ``files``
  list says what that run wrote); a file only when it is an earlier output of the same table.
  The working, home and project-root folders are never an output folder.
* Files and directories get the permissions the user's umask asks for (0644 / 0755 under the
  usual 022), not the 0600 of ``mkstemp``.
* :func:`check_output_dir` and :func:`check_output_file` refuse an unusable ``--out`` before
  any computation.
"""

from __future__ import annotations

import csv
import io
import json
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


RUN_FILE = "run.json"
"""The manifest every run folder holds (:mod:`qkf.core.manifest`); its ``kind`` says which
command wrote the folder and its ``files`` list what that command wrote there."""

_PROJECT_ROOT = Path(__file__).resolve().parents[2]


def protected_dirs() -> dict[Path, str]:
    """Folders no command may use as ``--out`` (nor any folder that holds one of them): the
    working directory, the home directory and the project root (a source checkout)."""
    found = {
        Path.cwd().resolve(): "the working directory",
        Path.home().resolve(): "the home directory",
    }
    if (_PROJECT_ROOT / "pyproject.toml").is_file():
        found.setdefault(_PROJECT_ROOT, "the qkf project root")
    return found


def _nonempty(raw: str | Path) -> Path:
    if not str(raw).strip():
        raise OutputError("'': an empty path; give a folder or file name")
    return Path(raw)


def _check_parent(path: Path) -> Path:
    """Refuse a path under which nothing can be created: its nearest existing ancestor must be a
    directory in which a directory can really be made (a probe, created and removed at once:
    permission bits say nothing for root, and /proc or a read-only mount refuse anyway)."""
    base = path.absolute().parent
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        raise OutputError(f"{path}: {base} is not a directory")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".qkf-probe.", dir=base))
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise OutputError(f"{path}: cannot create anything in {base} ({reason})") from None
    return path


def _listing(folder: Path) -> list[str]:
    """Every file under ``folder``, as POSIX paths relative to it, sorted."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir())


def _run_info(folder: Path) -> dict[str, Any] | None:
    """The folder's ``run.json`` as a mapping, or None if it has none that can be read."""
    try:
        data = json.loads((folder / RUN_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _foreign(folder: Path, kind: str | None) -> str | None:
    """Why ``folder`` may not be replaced by a run of ``kind``, or None if it may: it must be
    empty, or hold nothing but an earlier qkf run of the same kind (every file listed in its
    ``run.json``). ``kind`` None: any qkf run will do."""
    entries = sorted(p.name for p in folder.iterdir())
    if not entries:
        return None
    info = _run_info(folder)
    shown = ", ".join(entries[:4]) + (", …" if len(entries) > 4 else "")
    if info is None or not isinstance(info.get("kind"), str):
        return f"holds files that are not a qkf run ({shown})"
    if kind is not None and info["kind"] != kind:
        return f"holds a qkf {info['kind']} run, not a {kind} run"
    listed = info.get("files")
    if not isinstance(listed, list):
        return (
            f"holds a qkf {info['kind']} run written before runs listed their files; "
            "remove it yourself or choose another folder"
        )
    extra = [f for f in _listing(folder) if f not in set(map(str, listed))]
    if extra:
        more = ", ".join(extra[:4]) + (", …" if len(extra) > 4 else "")
        return f"holds files that are not part of its qkf run ({more})"
    return None


def check_output_dir(
    path: str | Path, kind: str | None = None, overwrite: bool | None = None
) -> Path:
    """Refuse an output directory that cannot be used, before any work (``OutputError``).

    Always refused: an empty path, an existing file, a path under which nothing can be made,
    and the working, home or project-root folder (or one that holds them). With ``kind`` (the
    ``run.json`` kind of the command), an existing non-empty folder must hold nothing but an
    earlier run of that kind; ``overwrite`` not None: replacing that earlier run needs
    ``overwrite=True`` (the command line's ``--overwrite``).
    """
    path = _nonempty(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: exists and is not a directory")
    real = path.resolve()
    for folder, what in protected_dirs().items():
        if folder == real or folder.is_relative_to(real):
            held = "is" if folder == real else "holds"
            raise OutputError(f"{path}: {held} {what}; give a folder of its own")
    _check_parent(path)
    if kind is not None and path.is_dir():
        why = _foreign(path, kind)
        if why is not None:
            raise OutputError(f"{path}: {why}")
        if overwrite is False and any(path.iterdir()):
            raise OutputError(f"{path}: holds an earlier qkf {kind} run; --overwrite replaces it")
    return path


def check_output_file(path: str | Path, header: str | None = None) -> Path:
    """Refuse an output file path that cannot be written, before any work (``OutputError``).

    A path ending in a separator names a folder, not a file. An existing file is replaced only
    if it is an earlier output of the same table (its first line is ``header``), so a command
    never overwrites a file it did not write.
    """
    _nonempty(path)
    text = str(path)  # as given: Path() would drop the trailing separator
    if text.endswith(("/", os.sep)):
        raise OutputError(f"{text}: names a folder; give a file name (e.g. {text}out.csv)")
    path = Path(text)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory, not a file")
    if path.exists():
        if not path.is_file():
            raise OutputError(f"{path}: exists and is not a regular file")
        if header is not None and _first_line(path) != header:
            raise OutputError(
                f"{path}: exists and is not an earlier output of this command; "
                "remove it yourself or choose another file"
            )
        if not os.access(path, os.W_OK):
            raise OutputError(f"{path}: no permission to overwrite")
    return _check_parent(path)


def _first_line(path: Path) -> str | None:
    try:
        with path.open(encoding="utf-8", newline="") as f:
            return f.readline(65536).rstrip("\r\n")
    except (OSError, UnicodeDecodeError):
        return None


def _seal(stage: Path) -> str | None:
    """Record in the stage's ``run.json`` the files of the run (so that a later run may replace
    exactly these); returns the run's kind (None: the stage holds no manifest)."""
    info = _run_info(stage)
    if info is None:
        return None
    info["files"] = _listing(stage)
    atomic_write_text(stage / RUN_FILE, json.dumps(info, indent=2, ensure_ascii=False) + "\n")
    kind = info.get("kind")
    return kind if isinstance(kind, str) else None


@contextmanager
def staged_directory(path: str | Path) -> Iterator[Path]:
    """Write a run into a sibling temporary directory; on success it replaces ``path`` whole.

    Yields the staging directory. If the block raises, the staging directory is removed and
    ``path`` is left as it was. The run's ``run.json`` (if the block wrote one) gets the list of
    its files. ``path`` is replaced only if it is empty or holds nothing but an earlier run of
    the same kind (checked again at the swap: never delete what qkf did not write); otherwise
    the finished run is kept beside it and ``OutputError`` says where. The swap is two renames
    (old aside, new in) followed by the removal of the old directory, so at no moment does
    ``path`` hold a mixture of two runs.
    """
    path = check_output_dir(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".staging", dir=path.parent))
    try:
        yield stage
        os.chmod(stage, dir_mode())
        kind = _seal(stage)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    why = _foreign(path, kind) if path.is_dir() else None
    if why is None and path.is_dir() and kind is None and any(path.iterdir()):
        why = "is not empty and this output has no run.json to match it with"
    if why is not None:
        kept = Path(tempfile.mkdtemp(prefix=f"{path.name}.new-", dir=path.parent))
        os.replace(stage, kept / path.name)
        raise OutputError(
            f"{path}: {why}; left as it was, the new results are in {kept / path.name}"
        )
    old = None
    if path.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
        os.replace(path, old / path.name)
    os.replace(stage, path)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


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
