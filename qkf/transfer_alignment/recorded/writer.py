"""Writing a simulated trial as a recorded run (``qkf record``; the ``--data`` format).

Numbers are written in their shortest round-trip form (pyarrow's CSV writer; Parquet stores
the float64 bits), so reading the file back gives the simulated arrays bit for bit. Epochs
without an ADS measurement get empty ADS cells. The file is written beside its destination,
flushed to disk and then moved into place: never half a file, and never over an existing one
unless asked (without ``overwrite`` the move is a hard link, which fails if the name appeared
meanwhile).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from qkf.core.io import file_mode
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.recorded.columns import (
    ADS_Q,
    ADS_RATE,
    EXTENSIONS,
    GYRO,
    TIME,
    TRUE_BIAS,
    TRUE_P,
    TRUE_Q,
)
from qkf.transfer_alignment.recorded.reader import RecordedDataError
from qkf.transfer_alignment.scenario import ScenarioData, simulate

ROW_GROUP_ROWS = 65_536
"""Rows per Parquet row group: a reader decodes a row group at a time (pyarrow's
``iter_batches`` too), so this bounds what reading holds beside the result."""


def recorded_table(data: ScenarioData, row: int = 0, *, truth: bool = True) -> pa.Table:
    """Trial ``row`` of ``data`` as a table of the recorded-run columns (absent ADS: null)."""
    if not 0 <= row < data.n_trials:
        raise IndexError(f"row {row}: the data hold {data.n_trials} trial(s)")
    n = data.n_epochs
    present = np.broadcast_to(np.asarray(data.has_meas, dtype=bool), (data.n_trials, n))[row]
    absent = ~present
    cols: dict[str, pa.Array] = {}

    def put(names: tuple[str, ...], values: np.ndarray, mask: np.ndarray | None = None) -> None:
        values = np.asarray(values, dtype=np.float64).reshape(n, len(names))
        shown = values if mask is None else values[~mask]
        if not np.isfinite(shown).all():
            raise ValueError(f"{names[0]} …: NaN or inf in trial row {row}; not writable")
        for j, name in enumerate(names):
            cols[name] = pa.array(np.ascontiguousarray(values[:, j]), pa.float64(), mask=mask)

    put((TIME,), data.t)
    put(ADS_Q, data.ads_q[row], absent)
    put(ADS_RATE, data.ads_rate[row], absent)
    put(GYRO, data.gyro[row])
    if truth:
        put(TRUE_Q, data.q_true[row])
        put(TRUE_BIAS, data.bias[row])
        put(TRUE_P, data.calib[row])
    return pa.table(cols)


def _kind(path: Path) -> str:
    kind = EXTENSIONS.get(path.suffix.lower())
    if kind is None:
        raise RecordedDataError(f"{path}: give a .csv, .parquet or .pq file")
    return kind


def _check_target(path: Path, overwrite: bool) -> None:
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, not a file")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; not overwritten (overwrite=True replaces it)")


@contextmanager
def _new_file(path: Path, overwrite: bool) -> Iterator[BinaryIO]:
    """A temporary file beside ``path``, moved onto it when the block succeeds (fsync first);
    removed if the block fails."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
            os.fchmod(f.fileno(), file_mode())  # not mkstemp's 0600
        if overwrite:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)  # never replaces: fails if the name exists by now
            except FileExistsError:
                raise FileExistsError(f"{path}: exists; not overwritten") from None
            except OSError:  # a file system without hard links
                _check_target(path, overwrite)
                os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def write_recorded(
    path: str | Path,
    data: ScenarioData,
    row: int = 0,
    *,
    truth: bool = True,
    overwrite: bool = False,
) -> None:
    """Write trial ``row`` of ``data`` to ``path`` (.csv, or .parquet / .pq), atomically.

    Reading it back (:func:`~.reader.read_recorded`) gives the arrays bit for bit. An existing
    file is refused (``FileExistsError``) unless ``overwrite``.
    """
    path = Path(path)
    kind = _kind(path)
    _check_target(path, overwrite)
    table = recorded_table(data, row, truth=truth)
    with _new_file(path, overwrite) as f:
        if kind == "csv":
            f.write((",".join(table.column_names) + "\n").encode())  # pyarrow quotes names
            pacsv.write_csv(
                table,
                f,
                write_options=pacsv.WriteOptions(include_header=False, quoting_style="none"),
            )
        else:
            pq.write_table(table, f, row_group_size=ROW_GROUP_ROWS)


def simulate_to_file(
    cfg: Config,
    seed: int,
    trial: int,
    path: str | Path,
    *,
    truth: bool = True,
    overwrite: bool = False,
) -> None:
    """Simulate trial ``trial`` of seed ``seed`` (as in a run of many trials: the trial's own
    streams) and write it as a recorded run."""
    path = Path(path)
    _kind(path)
    _check_target(path, overwrite)  # before the simulation, which may take a while
    write_recorded(path, simulate(cfg, seed, [trial]), 0, truth=truth, overwrite=overwrite)
