"""Writing a simulated trial as a recorded run (``qkf record``; the ``--data`` format).

Numbers are written in their shortest round-trip form (pyarrow's CSV writer; Parquet stores
the float64 bits), so reading the file back gives the simulated arrays bit for bit. Epochs
without an ADS measurement get empty ADS cells. The file is written beside its destination
and renamed into place: never half a file, and never over an existing one unless asked.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

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
from qkf.transfer_alignment.scenario import ScenarioData, simulate


def recorded_table(data: ScenarioData, row: int = 0, *, truth: bool = True) -> pa.Table:
    """Trial ``row`` of ``data`` as a table of the recorded-run columns."""
    meas = np.broadcast_to(np.asarray(data.has_meas, dtype=bool), (data.n_trials, data.n_epochs))
    present = meas[row]
    cols: dict[str, pa.Array] = {TIME: pa.array(np.asarray(data.t, dtype=float))}

    def put(names: tuple[str, ...], values: np.ndarray, mask: np.ndarray | None = None) -> None:
        for j, name in enumerate(names):
            cols[name] = pa.array(np.ascontiguousarray(values[:, j]), pa.float64(), mask=mask)

    absent = ~present
    put(ADS_Q, data.ads_q[row], absent)
    put(ADS_RATE, data.ads_rate[row], absent)
    put(GYRO, data.gyro[row])
    if truth:
        put(TRUE_Q, data.q_true[row])
        put(TRUE_BIAS, data.bias[row])
        put(TRUE_P, data.calib[row])
    return pa.table(cols)


def write_recorded(
    path: str | Path,
    data: ScenarioData,
    row: int = 0,
    *,
    truth: bool = True,
    overwrite: bool = False,
) -> None:
    """Write trial ``row`` of ``data`` to ``path`` (.csv or .parquet), atomically."""
    path = Path(path)
    kind = EXTENSIONS.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"{path}: give a .csv, .parquet or .pq file")
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; not overwritten")
    table = recorded_table(data, row, truth=truth)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        if kind == "csv":
            with open(tmp, "wb") as f:  # a plain header (pyarrow would quote the names)
                f.write((",".join(table.column_names) + "\n").encode())
                pacsv.write_csv(
                    table,
                    f,
                    write_options=pacsv.WriteOptions(include_header=False, quoting_style="none"),
                )
        else:
            pq.write_table(table, tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def simulate_to_file(
    cfg: Config,
    seed: int,
    trial: int,
    path: str | Path,
    *,
    truth: bool = True,
    overwrite: bool = False,
) -> None:
    """Simulate trial ``trial`` of seed ``seed`` and write it as a recorded run."""
    write_recorded(path, simulate(cfg, seed, [trial]), 0, truth=truth, overwrite=overwrite)
