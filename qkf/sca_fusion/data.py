"""Input files and arcs (docs/sca_fusion.md, "Input files" and "Arcs").

``SCA.csv``: ``t_s, q_x, q_y, q_z, q_w`` (body → inertial, scalar last); ``ACC.csv``:
``t_s, dw_x, dw_y, dw_z`` (rad/s², body). Other columns are ignored. A file is refused — with
its path, the row (1-based data row, and the line of the file) and the column — when a column
is missing or appears twice, a value is not a finite number, time does not increase, or a
quaternion's norm differs from 1 by more than the tolerance. Then :func:`check_pair` judges the
two files together: each needs enough epochs for one arc, and the two must cover the same time
(see its docstring for the rules). Nothing is computed before both files pass.

The epochs of the two files are merged (within a matching tolerance) into one grid, which is
split into arcs wherever the spacing departs from the nominal step.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from qkf.core.csvfile import DataFileError, read_records, where
from qkf.sca_fusion.config import FusionConfig
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


# The default least share of each file's time span the other file must cover (see check_pair;
# the config's data.min_overlap_fraction). Half: below it most of the output would come from
# one instrument alone, which is what a wrong file (another day, another satellite) or a wrong
# time unit looks like, not a fusion.
MIN_OVERLAP_FRACTION = 0.5

# Time units a t_s column is commonly written in by mistake, as powers of ten of the second: a
# refused pair where one file spans about 10**k times what the other spans blames that unit.
_UNITS = ((3, "milliseconds"), (6, "microseconds"), (9, "nanoseconds"))


def _num(x: float) -> str:
    """A plain number for messages: ``1``, ``0.1``, ``3599000``, never ``np.float64(…)``."""
    return f"{float(x):.12g}"


def _span(s: Series) -> str:
    return f"{s.path}: t_s {_num(s.t[0])} to {_num(s.t[-1])} s"


def _duration(s: Series) -> float:
    return float(s.t[-1] - s.t[0])


def _unit_suspect(big: Series, small: Series) -> tuple[int, str] | None:
    """``(k, unit)`` when ``big`` spans about 10**k times what ``small`` spans (k = 3, 6, 9:
    milli-, micro-, nanoseconds), else None. Only consulted for a pair already refused, so the
    band (a factor 10**0.1 ≈ 1.26 either way) decides the wording, never acceptance."""
    a, b = _duration(big), _duration(small)
    if a <= 0.0 or b <= 0.0:
        return None
    ratio = float(np.log10(a / b))
    for k, unit in _UNITS:
        if abs(ratio - k) < 0.1:
            return k, unit
    return None


def check_pair(
    sca: Series,
    acc: Series,
    cfg: FusionConfig,
    min_overlap_fraction: float = MIN_OVERLAP_FRACTION,
) -> None:
    """Refuse a star-camera/accelerometer pair the fusion cannot use, naming the file and the
    problem (raises :class:`DataError`); call it after both files have been read.

    Rules, in order:

    - rows: each file has at least the epochs of the shortest arc the fusion solves,
      ``max(arcs.min_epochs, estimator.interpolation_degree + 1)`` (shorter arcs are skipped,
      so fewer rows cannot give a fused arc with that instrument in it);
    - overlap: the two time spans share more than ``data.time_match_tolerance_s`` (s);
    - coverage: the shared time is at least ``min_overlap_fraction`` of each file's span.

    When the pair fails the overlap or coverage rule and one file spans about 10³, 10⁶ or 10⁹
    times what the other spans, the message blames that file's time unit instead (``t_s`` in
    milli-, micro- or nanoseconds).
    """
    need = max(cfg.arcs.min_epochs, cfg.estimator.interpolation_degree + 1)  # as run_fusion
    for s, what in ((sca, "star-camera"), (acc, "accelerometer")):
        if s.t.size < need:
            raise DataError(
                f"{s.path}: {s.t.size} data row{'s' if s.t.size != 1 else ''}; the fusion "
                f"needs at least {need} {what} epochs, the shortest arc it solves (the larger "
                "of arcs.min_epochs and estimator.interpolation_degree + 1)"
            )
    shared = min(float(sca.t[-1]), float(acc.t[-1])) - max(float(sca.t[0]), float(acc.t[0]))
    disjoint = shared <= cfg.data.time_match_tolerance_s
    # each file is judged by the share of the OTHER file's span it covers; the worse is named
    fraction, s, other, name = min(
        (max(shared, 0.0) / _duration(sca), acc, sca, "star camera"),
        (max(shared, 0.0) / _duration(acc), sca, acc, "accelerometer"),
        key=lambda x: x[0],
    )
    if not disjoint and fraction >= min_overlap_fraction:
        return
    big, small = (sca, acc) if _duration(sca) >= _duration(acc) else (acc, sca)
    suspect = _unit_suspect(big, small)
    if suspect is not None:  # the longer file is the one at fault
        k, unit = suspect
        raise DataError(
            f"{big.path}: column t_s: spans {_num(_duration(big))} s, about 10^{k} times the "
            f"{_num(_duration(small))} s of {small.path}: are its times in {unit}? t_s must be "
            f"seconds ({_span(big)}; {_span(small)})"
        )
    if disjoint:
        raise DataError(
            f"{sca.path} and {acc.path} do not overlap in time ({_span(sca)}; {_span(acc)}): "
            "the star camera and the accelerometer must observe the same time"
        )
    raise DataError(
        f"{s.path}: covers {_num(shared)} s of the {_num(_duration(other))} s the {name} "
        f"covers ({100 * fraction:.3g} %; {_span(s)}; {_span(other)}); each file must cover at "
        f"least {100 * min_overlap_fraction:.3g} % of the other's time span (crop both to "
        "their common time)"
    )


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
