"""Input files and arcs (docs/sca_fusion.md, "Input files" and "Arcs").

``SCA.csv``: ``t_s, q_x, q_y, q_z, q_w`` (body → inertial, scalar last); ``ACC.csv``:
``t_s, dw_x, dw_y, dw_z`` (rad/s², body). Other columns are ignored. A file is refused — with
its path, the row (1-based data row, and the line of the file) and the column — when a column
is missing, a value is not a finite number, time does not increase, or a quaternion's norm
differs from 1 by more than the tolerance. Nothing is computed before both files pass.

The epochs of the two files are merged (within a matching tolerance) into one grid, which is
split into arcs wherever the spacing departs from the nominal step.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from qkf.core.csvfile import DataFileError, read_records, where
from qkf.sca_fusion.differentiation import sign_continuous

SCA_COLUMNS = ("t_s", "q_x", "q_y", "q_z", "q_w")
ACC_COLUMNS = ("t_s", "dw_x", "dw_y", "dw_z")


DataError = DataFileError  # this problem's name for it


@dataclass(frozen=True)
class Series:
    """One input file: times (n,) s and values (n, k)."""

    path: str
    t: np.ndarray
    values: np.ndarray
    row: np.ndarray | None = None  # (n,) the file row of each epoch (for messages)


def read_series(
    path: str | Path, columns: tuple[str, ...], time_tolerance_s: float = 0.0
) -> Series:
    """Read the named columns of a CSV file with a header; check numbers and time order."""
    p = Path(path)
    records = read_records(p, columns)
    line = [k for k, _ in records]  # file row of each record (blank lines are skipped)
    rows = [rec for _, rec in records]
    raw = np.array(rows, dtype=object)
    values = np.empty(raw.shape)
    for j, col in enumerate(columns):
        try:
            values[:, j] = raw[:, j].astype(float)
        except ValueError:
            for k, text in enumerate(raw[:, j]):
                try:
                    float(text)
                except ValueError:
                    raise DataError(
                        f"{where(p, line[k])}, column {col}: {text!r} is not a number"
                    ) from None
        bad = ~np.isfinite(values[:, j])
        if bad.any():
            k = int(np.argmax(bad))
            raise DataError(f"{where(p, line[k])}, column {col}: non-finite value {raw[k, j]!r}")
    t = values[:, 0]
    step = np.diff(t)
    bad = step <= time_tolerance_s
    if bad.any():
        k = int(np.argmax(bad)) + 1
        raise DataError(
            f"{where(p, line[k])}, column t_s: time {raw[k, 0]} does not increase after "
            f"{raw[k - 1, 0]} (row {line[k - 1]})"
            + (f" by more than {time_tolerance_s:g} s" if time_tolerance_s > 0 else "")
        )
    return Series(str(p), t, values[:, 1:], np.asarray(line))


def read_sca(path: str | Path, norm_tolerance: float, time_tolerance_s: float = 0.0) -> Series:
    """Star-camera quaternions; refuses a norm off 1 by more than ``norm_tolerance``, then
    normalises."""
    s = read_series(path, SCA_COLUMNS, time_tolerance_s)
    norm = np.linalg.norm(s.values, axis=1)
    bad = np.abs(norm - 1.0) > norm_tolerance
    if bad.any():
        k = int(np.argmax(bad))
        row = k + 1 if s.row is None else int(s.row[k])
        raise DataError(
            f"{where(Path(path), row)}, columns q_x, q_y, q_z, q_w: quaternion norm "
            f"{norm[k]:.9g} differs from 1 by more than {norm_tolerance:g}"
        )
    return Series(s.path, s.t, s.values / norm[:, None], s.row)


def read_acc(path: str | Path, time_tolerance_s: float = 0.0) -> Series:
    """Angular accelerations (rad/s², body)."""
    return read_series(path, ACC_COLUMNS, time_tolerance_s)


@dataclass(frozen=True)
class ArcData:
    """One arc on a uniform grid: ``has_sca``/``has_acc`` (n,) masks; ``sca_q`` (n, 4),
    sign-continuous over the star-camera epochs (NaN elsewhere); ``acc`` (n, 3) (NaN where
    missing)."""

    t: np.ndarray
    dt: float
    has_sca: np.ndarray
    sca_q: np.ndarray
    has_acc: np.ndarray
    acc: np.ndarray

    @property
    def n(self) -> int:
        return int(self.t.size)

    def taylor_point(self) -> np.ndarray:
        """Star camera at its epochs, slerp between them, nearest beyond the ends (n, 4)."""
        ts, qs = self.t[self.has_sca], self.sca_q[self.has_sca]
        if ts.size == 1:
            return np.repeat(qs, self.n, axis=0)
        tt = np.clip(self.t, ts[0], ts[-1])
        q = Slerp(ts, Rotation.from_quat(qs))(tt).as_quat()
        q[self.has_sca] = qs
        return sign_continuous(q)


@dataclass(frozen=True)
class Arcs:
    arcs: list[ArcData]
    skipped: list[str]  # why each skipped piece was skipped
    dt: float


def split_arcs(
    sca_t: np.ndarray,
    sca_q: np.ndarray,
    acc_t: np.ndarray,
    acc: np.ndarray,
    match_tolerance_s: float,
    spacing_tolerance: float,
    min_epochs: int,
) -> Arcs:
    """Merge the two series into one epoch grid and split it into uniform arcs."""
    all_t = np.sort(np.concatenate([sca_t, acc_t]))
    new = np.concatenate([[True], np.diff(all_t) > match_tolerance_s])
    grid = all_t[new]
    if grid.size < 2:
        return Arcs([], [f"only {grid.size} epoch"], np.nan)
    sca_e = np.searchsorted(grid, sca_t + match_tolerance_s, side="right") - 1
    acc_e = np.searchsorted(grid, acc_t + match_tolerance_s, side="right") - 1
    has_sca = np.zeros(grid.size, dtype=bool)
    has_acc = np.zeros(grid.size, dtype=bool)
    q_all = np.full((grid.size, 4), np.nan)
    a_all = np.full((grid.size, 3), np.nan)
    has_sca[sca_e] = True
    has_acc[acc_e] = True
    q_all[sca_e] = sign_continuous(sca_q)
    a_all[acc_e] = acc
    step = np.diff(grid)
    dt = float(np.median(step))
    breaks = np.flatnonzero(np.abs(step - dt) > spacing_tolerance * dt) + 1
    arcs, skipped = [], []
    for lo, hi in zip(np.r_[0, breaks], np.r_[breaks, grid.size], strict=True):
        t = grid[lo:hi]
        where = f"{t[0]:.6g} s to {t[-1]:.6g} s ({hi - lo} epochs)"
        if hi - lo < min_epochs:
            skipped.append(f"{where}: shorter than {min_epochs} epochs")
            continue
        if not has_sca[lo:hi].any():
            skipped.append(f"{where}: no star-camera epoch")
            continue
        arc_dt = float(np.mean(np.diff(t)))
        arcs.append(ArcData(t, arc_dt, has_sca[lo:hi], q_all[lo:hi], has_acc[lo:hi], a_all[lo:hi]))
    return Arcs(arcs, skipped, dt)
