r"""Recorded runs on the filter's time grid: files → one ``ScenarioData`` (docs/recorded_data.md).

Every method takes a :class:`~qkf.transfer_alignment.scenario.ScenarioData` (trials × epochs on
a uniform step), so recorded files are put on such a grid here, and the methods, the policy
runner and the environment run on them unchanged:

- the step ``Δt`` is the median of the file's row steps; row ``i`` sits at epoch
  ``k_i = round((t_i − t_0)/Δt)`` and must lie within ``recorded.step_tolerance · Δt`` of it
  (else the file is refused, row named);
- a row step of ``m Δt`` (dropped samples) becomes ``m`` epochs: the row's own and ``m − 1``
  *held* epochs with the same gyro reading and no measurement. With the rate held over the
  interval this is exact: the error dynamics are time-invariant while ``ω̃`` is constant, so
  ``m`` steps of ``Δt`` compose to one step of ``m Δt`` (transition and process noise alike);
- an epoch updates (``has_meas``) when its row has every measurement the filter uses: the ADS
  attitude, and the ADS rate too with ``filter.matching: attitude_rate``. A row with only
  one of the two is counted (``partial_rows``) and filtered without an update;
- the run starts at the first row with an ADS attitude (``Ĉ_0`` is that attitude); rows before
  it are counted (``skipped_rows``), not used;
- a stretch without updates longer than ``recorded.max_gap_s`` refuses the file (row named);
  shorter ones are propagated through;
- truth columns, when present, are interpolated at the held epochs (slerp for the attitude,
  linear for bias and calibration), so errors are defined at every epoch.

Several files are trials of one run: they must give the same step and the same number of grid
epochs (a paired comparison needs the same epochs for every trial).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.recorded.conventions import check_conventions
from qkf.transfer_alignment.recorded.reader import (
    ReadLimits,
    RecordedDataError,
    RecordedRun,
    data_files,
    read_recorded,
)
from qkf.transfer_alignment.scenario import ScenarioData


@dataclass(frozen=True)
class GridInfo:
    """How one file was put on the grid."""

    path: Path
    sha256: str
    rows: int  # data rows in the file
    first_row: int  # 0-based index of the first row used (the first with an ADS attitude)
    epoch: np.ndarray  # (rows used,) grid epoch of each row used
    t_s: np.ndarray  # (rows used,) the rows' own times, s
    t0_s: float  # the file's time of grid epoch 0
    held_epochs: int  # epochs inserted for dropped samples
    partial_rows: int  # rows with an ADS attitude or rate but not every measurement used
    updates: int  # epochs with a measurement update
    max_offset_s: float  # largest |t_i − t_0 − k_i Δt|


@dataclass(frozen=True)
class RecordedSet:
    """Recorded files as the trials of one run."""

    cfg: Config  # the config with the data's step, duration and trial count
    base_cfg: Config  # the config as given: its simulated scenario sets the state_settled weights
    data: ScenarioData  # truth arrays NaN without truth columns
    files: tuple[GridInfo, ...]
    has_truth: bool

    def manifest(self) -> list[dict[str, object]]:
        """What ``run.json`` says of the data files."""
        return [
            {
                "path": str(f.path),
                "sha256": f.sha256,
                "rows": f.rows,
                "rows_used": int(f.epoch.size),
                "held_epochs": f.held_epochs,
                "partial_rows": f.partial_rows,
                "updates": f.updates,
            }
            for f in self.files
        ]


def read_limits(cfg: Config) -> ReadLimits:
    """The reader's limits from ``recorded`` (the epoch limit bounds the rows too)."""
    rc = cfg.recorded
    return ReadLimits(
        max_rows=rc.max_epochs,
        quaternion_tolerance=rc.quaternion_tolerance,
        max_rate_rad_s=rc.max_rate_rad_s,
        chunk_rows=rc.chunk_rows,
        ignore_columns=frozenset(rc.ignore_columns),
    )


def grid_step(t: np.ndarray) -> float:
    """The grid step of a file: the median row step, s."""
    return float(np.median(np.diff(t)))


def _where(path: Path, row: int) -> str:
    return f"{path}: row {row + 1} (line {row + 2})"


@dataclass(frozen=True)
class _Placed:
    info: GridInfo
    dt: float
    n: int


def place_rows(run: RecordedRun, cfg: Config) -> _Placed:
    """Grid epochs of ``run``'s rows, checked against ``recorded`` (module doc)."""
    rc = cfg.recorded
    use_rate = cfg.filter.matching == "attitude_rate"
    att = run.has_attitude
    if not att.any():
        raise RecordedDataError(f"{run.path}: no row has an ADS attitude (ads_qx … ads_qw)")
    first = int(np.argmax(att))
    t = run.t[first:]
    if t.size < 2:
        raise RecordedDataError(
            f"{run.path}: one row from the first ADS attitude on (row {first + 1}); a run needs two"
        )
    dt = grid_step(t)
    pos = (t - t[0]) / dt
    k = np.rint(pos).astype(np.int64)
    off = np.abs(pos - k)
    bad = np.flatnonzero((off > rc.step_tolerance) | (np.diff(k, prepend=-1) < 1))
    if bad.size:
        i = int(bad[0])
        ti, t0 = float(t[i]), float(t[0])
        raise RecordedDataError(
            f"{_where(run.path, first + i)}, column t_s: t = {ti!r} s is {off[i]:.3g} steps off "
            f"the grid of step {dt:.6g} s (the median row step) started at t = {t0!r} s; rows "
            f"must lie within recorded.step_tolerance = {rc.step_tolerance:g} step of it "
            "(the step may vary only by whole steps: dropped samples)"
        )
    n = int(k[-1]) + 1
    if n > rc.max_epochs:
        raise RecordedDataError(
            f"{run.path}: {n:,} epochs of {dt:.6g} s on the grid (with the dropped samples "
            f"filled in); over the epoch limit recorded.max_epochs = {rc.max_epochs:,}"
        )
    rate = run.has_rate[first:]
    used = att[first:] & (rate if use_rate else True)
    partial = (att[first:] | rate) & ~used
    _check_gaps(run.path, first, t, used, rc.max_gap_s)
    info = GridInfo(
        path=run.path,
        sha256=run.sha256,
        rows=run.n_rows,
        first_row=first,
        epoch=k,
        t_s=t,
        t0_s=float(t[0]),
        held_epochs=n - int(k.size),
        partial_rows=int(np.count_nonzero(partial)),
        updates=int(np.count_nonzero(used)),
        max_offset_s=float(off.max() * dt),
    )
    return _Placed(info, dt, n)


def _check_gaps(path: Path, first: int, t: np.ndarray, used: np.ndarray, limit: float) -> None:
    """Refuse a stretch of more than ``limit`` s without an update (the end of the file too)."""
    idx = np.flatnonzero(used)
    if idx.size == 0:
        raise RecordedDataError(
            f"{path}: no row has every measurement the filter uses (the ADS attitude, and the ADS "
            "rate with filter.matching attitude_rate)"
        )
    times = np.concatenate([[t[0]], t[idx], [t[-1]]])
    gaps = np.diff(times)
    j = int(np.argmax(gaps))
    if gaps[j] > limit:
        # the row that ends the gap (the last row for a gap that runs to the end)
        end = idx[j] if j < idx.size else t.size - 1
        raise RecordedDataError(
            f"{_where(path, first + int(end))}: {gaps[j]:.6g} s without an ADS measurement the "
            f"filter uses (t = {float(times[j])!r} … {float(times[j + 1])!r} s); longer than "
            f"recorded.max_gap_s = {limit:g} s"
        )


def _hold(values: np.ndarray, epoch: np.ndarray, n: int) -> np.ndarray:
    """Per grid epoch, the value of the last row at or before it (rows at ``epoch``)."""
    if epoch.size == n:  # no dropped sample: the rows themselves
        return values
    owner = np.searchsorted(epoch, np.arange(n), side="right") - 1
    return values[owner]


def _interpolate_truth(
    values: np.ndarray, q: np.ndarray, epoch: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Truth at every grid epoch: linear in ``values`` (rows, m), slerp in ``q`` (rows, 4)."""
    grid = np.arange(n)
    lin = np.stack([np.interp(grid, epoch, values[:, j]) for j in range(values.shape[1])], axis=1)
    owner = np.minimum(np.searchsorted(epoch, grid, side="right") - 1, epoch.size - 2)
    span = (epoch[owner + 1] - epoch[owner]).astype(float)
    frac = np.clip((grid - epoch[owner]) / span, 0.0, 1.0)
    r0 = Rotation.from_quat(q[owner])
    rel = (r0.inv() * Rotation.from_quat(q[owner + 1])).as_rotvec()
    q_grid = (r0 * Rotation.from_rotvec(rel * frac[:, None])).as_quat()
    exact = np.zeros(n, dtype=bool)
    exact[epoch] = True
    q_grid[exact] = q  # the rows' own truth, bit for bit
    return lin, q_grid


@dataclass(frozen=True)
class _Trial:
    gyro: np.ndarray
    ads_q: np.ndarray
    ads_rate: np.ndarray
    has_meas: np.ndarray
    q_true: np.ndarray | None
    bias: np.ndarray | None
    calib: np.ndarray | None


def _on_grid(run: RecordedRun, placed: _Placed, use_rate: bool) -> _Trial:
    info, n = placed.info, placed.n
    sl = slice(info.first_row, None)
    k = info.epoch
    ads_q = run.ads_q[sl]
    ads_rate = run.ads_rate[sl]
    has_meas = np.zeros(n, dtype=bool)
    used = run.has_attitude[sl] & (run.has_rate[sl] if use_rate else True)
    has_meas[k[used]] = True
    # absent ADS values are never read by a filter (no update there); they hold the last
    # present one so that every array stays finite for vectorised methods
    q_rows = _fill_forward(ads_q)
    w_rows = _fill_forward(ads_rate, default=0.0)
    truth = run.truth
    if truth is None:
        q_true = bias = calib = None
    elif info.held_epochs == 0:
        q_true, bias, calib = truth.q[sl], truth.bias[sl], truth.calib[sl]
    else:
        lin, q_true = _interpolate_truth(
            np.concatenate([truth.bias[sl], truth.calib[sl]], axis=1), truth.q[sl], k, n
        )
        bias, calib = lin[:, :3], lin[:, 3:]
    return _Trial(
        gyro=_hold(run.gyro[sl], k, n),
        ads_q=_hold(q_rows, k, n),
        ads_rate=_hold(w_rows, k, n),
        has_meas=has_meas,
        q_true=q_true,
        bias=bias,
        calib=calib,
    )


def _fill_forward(values: np.ndarray, default: float | None = None) -> np.ndarray:
    """Rows with NaN take the last finite row before them (``default``, else the first finite
    row, before any)."""
    ok = np.isfinite(values).all(axis=1)
    if ok.all():
        return values
    idx = np.where(ok, np.arange(ok.size), -1)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(ok)) if ok.any() else -1
    out = values[np.where(idx < 0, max(first, 0), idx)]
    if first < 0 or default is not None:
        out[idx < 0] = 0.0 if default is None else default
    return out


def load_recorded(cfg: Config, paths: Sequence[str | Path]) -> RecordedSet:
    """Read recorded files (or folders of them) as the trials of one run on ``cfg``.

    Returns the config with the data's step (``scenario.dt_s``), duration and trial count, and
    the data. :class:`RecordedDataError` (exit 2) names the file, row and column of bad input.
    """
    files = data_files(paths)
    limits = read_limits(cfg)
    params = FilterParams.from_config(cfg)
    use_rate = cfg.filter.matching == "attitude_rate"
    trials: list[_Trial] = []
    infos: list[GridInfo] = []
    dt = n = None
    for path in files:
        run = read_recorded(path, limits)
        if cfg.recorded.check_conventions:
            check_conventions(run, params.sigma_a, float(params.p0_sigma[3:6].max()))
        placed = place_rows(run, cfg)
        if dt is None:
            dt, n = placed.dt, placed.n
        elif not (abs(placed.dt - dt) <= 1e-9 * dt and placed.n == n):
            raise RecordedDataError(
                f"{path}: {placed.n:,} epochs of {placed.dt:.9g} s, but {files[0]} has {n:,} of "
                f"{dt:.9g} s; the files of one run are its trials and must share the grid "
                "(run files of other lengths separately)"
            )
        trials.append(_on_grid(run, placed, use_rate))
        infos.append(placed.info)
        del run  # one file's rows in memory at a time
    assert dt is not None and n is not None
    has_truth = all(tr.q_true is not None for tr in trials)
    if not has_truth and any(tr.q_true is not None for tr in trials):
        with_t = [str(i.path) for i, tr in zip(infos, trials, strict=True) if tr.q_true is not None]
        raise RecordedDataError(
            f"{with_t[0]}: has truth columns but other files of the run do not; give all of "
            "them truth or none"
        )
    b = len(trials)
    nan = np.nan

    def stack(name: str, width: int) -> np.ndarray:
        if not has_truth:  # a read-only view: no memory for a day of NaN
            return np.broadcast_to(np.full(width, nan), (b, n, width))
        return trials_of(name)

    masks = np.stack([tr.has_meas for tr in trials])

    def trials_of(name: str) -> np.ndarray:  # one file: a view, not a copy of a day of data
        parts = [getattr(tr, name) for tr in trials]
        return parts[0][None] if len(parts) == 1 else np.stack(parts)

    data = ScenarioData(
        t=np.arange(n) * dt,
        dt=dt,
        omega_true=np.broadcast_to(np.full(3, nan), (b, n, 3)),
        q_true=stack("q_true", 4),
        bias=stack("bias", 3),
        calib=stack("calib", 9),
        gyro=trials_of("gyro"),
        ads_q=trials_of("ads_q"),
        ads_rate=trials_of("ads_rate"),
        # one mask for all trials when they agree (what every method has always been given)
        has_meas=masks[0].copy() if (masks == masks[0]).all() else masks,
        trial_ids=np.arange(b),
        seed=0,
    )
    run_cfg = cfg.model_copy(
        update={
            "scenario": cfg.scenario.model_copy(update={"dt_s": dt, "duration_s": n * dt}),
            "run": cfg.run.model_copy(update={"trials": b}),
        }
    )
    return RecordedSet(
        cfg=revalidated(run_cfg), base_cfg=cfg, data=data, files=tuple(infos), has_truth=has_truth
    )


def revalidated(cfg: Config) -> Config:
    """``cfg`` validated again (a ``model_copy`` skips the validators: the epoch limits)."""
    return type(cfg).model_validate(cfg.model_dump())
