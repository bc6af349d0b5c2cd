"""Vector observations and the input file (docs/alignment.md, "Input file").

``DATA.csv`` has a header and one row per sensor observation: ``t_s, sensor, w_x, w_y, w_z,
r_x, r_y, r_z`` — the time (s), the sensor's name, the measured unit vector in the body frame
(through the nominal mounting) and the known unit reference vector in the inertial frame. Other
columns are ignored. Rows are in time order, ``t_s`` non-decreasing (the rows of one epoch,
one per observation, share a ``t_s``); observations of different sensors at the same ``t_s``
form the pairs. A file is refused — naming the file, the row (1-based data row and the line of
the file) and the column — when a column is missing or appears twice, a value is not a finite
number, a time is earlier than the row before it (by more than the time tolerance), a sensor is
not in the config, a vector's norm is off 1 by more than the tolerance, or a sensor of the
config is never observed at the same time as another sensor.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from qkf.core.csvfile import DataFileError, read_records, where

COLUMNS = ("t_s", "sensor", "w_x", "w_y", "w_z", "r_x", "r_y", "r_z")
NUMERIC = ("t_s", "w_x", "w_y", "w_z", "r_x", "r_y", "r_z")


DataError = DataFileError  # this problem's name for it


@dataclass(frozen=True)
class Observations:
    """Vector observations of the sensors ``names``: ``sensor`` (n,) indices into ``names``,
    ``t`` (n,) s, ``w`` (n, 3) measured body-frame unit vectors, ``r`` (n, 3) inertial unit
    reference vectors, ``row`` (n,) the 1-based data row of each (−1 when simulated)."""

    names: tuple[str, ...]
    t: np.ndarray
    sensor: np.ndarray
    w: np.ndarray
    r: np.ndarray
    row: np.ndarray
    source: str = "simulation"

    @property
    def n(self) -> int:
        return int(self.t.size)


def epoch_index(t: np.ndarray, tolerance_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Group times into epochs: returns ``(epoch (n,), epoch_times (E,))``; times closer than
    ``tolerance_s`` to the previous one (in sorted order) share its epoch."""
    order = np.argsort(t, kind="stable")
    ts = t[order]
    new = np.concatenate([[True], np.diff(ts) > tolerance_s])
    idx_sorted = np.cumsum(new) - 1
    epoch = np.empty(t.size, dtype=np.int64)
    epoch[order] = idx_sorted
    return epoch, ts[new]


def paired_sensors(obs: Observations, tolerance_s: float) -> np.ndarray:
    """Per sensor of ``obs.names``: whether it is observed at least once at an epoch where
    another sensor is observed too (bool array)."""
    epoch, times = epoch_index(obs.t, tolerance_s)
    s = len(obs.names)
    seen = np.zeros((times.size, s), dtype=bool)
    seen[epoch, obs.sensor] = True
    shared = seen.sum(axis=1) >= 2
    return np.asarray(seen[shared].any(axis=0), dtype=bool)


def read_data(
    path: str | Path, names: list[str], unit_tolerance: float, time_tolerance_s: float
) -> Observations:
    """Read and check ``DATA.csv`` for the sensors ``names`` (see the module docstring);
    vectors are normalised after the check. Raises :class:`DataError`."""
    p = Path(path)
    records = read_records(p, COLUMNS)

    lookup = {name: i for i, name in enumerate(names)}
    n = len(records)
    rows = np.array([k for k, _ in records], dtype=np.int64)
    sensor = np.empty(n, dtype=np.int64)
    values = np.empty((n, len(NUMERIC)))
    for j, (k, rec) in enumerate(records):
        name = rec[1]
        if name not in lookup:
            raise DataError(
                f"{where(p, k)}, column sensor: unknown sensor {name!r} "
                f"(the config has {', '.join(names)})"
            )
        sensor[j] = lookup[name]
        for c, col in enumerate(NUMERIC):
            text = rec[COLUMNS.index(col)]
            try:
                v = float(text)
            except ValueError:
                raise DataError(f"{where(p, k)}, column {col}: {text!r} is not a number") from None
            if not np.isfinite(v):
                raise DataError(f"{where(p, k)}, column {col}: non-finite value {text!r}")
            values[j, c] = v
        # Time order, checked row by row so the first bad row in the file is the one named.
        # Non-decreasing, not increasing: every observation of an epoch is a row of its own.
        # Within the tolerance, rows belong to one epoch and may come in either order.
        if j > 0 and values[j, 0] < values[j - 1, 0] - time_tolerance_s:
            prev_k, prev = records[j - 1]
            raise DataError(
                f"{where(p, k)}, column t_s: time {rec[0]} is earlier than {prev[0]} "
                f"(row {prev_k}); rows must be in time order (t_s non-decreasing: the rows of "
                "one epoch share a t_s)"
            )
    t, w, r = values[:, 0], values[:, 1:4], values[:, 4:7]
    for label, vec in (("w", w), ("r", r)):
        norm = np.linalg.norm(vec, axis=1)
        bad = np.abs(norm - 1.0) > unit_tolerance
        if bad.any():
            j = int(np.argmax(bad))
            raise DataError(
                f"{where(p, int(rows[j]))}, columns {label}_x, {label}_y, {label}_z: not a unit "
                f"vector (norm {norm[j]:.9g} differs from 1 by more than {unit_tolerance:g})"
            )
    obs = Observations(
        names=tuple(names),
        t=t,
        sensor=sensor,
        w=w / np.linalg.norm(w, axis=1, keepdims=True),
        r=r / np.linalg.norm(r, axis=1, keepdims=True),
        row=rows,
        source=str(p),
    )
    paired = paired_sensors(obs, time_tolerance_s)
    lonely = [names[i] for i in np.flatnonzero(~paired)]
    if lonely:
        detail = "; ".join(_lonely(nm, rows[sensor == names.index(nm)]) for nm in lonely)
        raise DataError(
            f"{p}: column sensor: sensor(s) never paired: {detail}; every sensor of the config "
            "needs observations at the same t_s as another sensor"
        )
    return obs


def _lonely(name: str, rows: np.ndarray) -> str:
    if rows.size == 0:
        return f"{name!r} (no rows)"
    shown = ", ".join(f"row {r} (line {r + 1})" for r in rows[:3])
    more = f" and {rows.size - 3} more" if rows.size > 3 else ""
    return f"{name!r} ({shown}{more}: never at the t_s of another sensor)"


def write_data_text(obs: Observations) -> str:
    """``obs`` in the ``DATA.csv`` format (full precision: reading it back gives the same)."""
    from qkf.core.io import csv_text

    rows = (
        [float(obs.t[i]), obs.names[obs.sensor[i]], *map(float, obs.w[i]), *map(float, obs.r[i])]
        for i in range(obs.n)
    )
    return csv_text(COLUMNS, rows)
