r"""Units and conventions of a recorded run, checked before any filtering (docs/recorded_data.md,
"Units and conventions").

The gyro measures the body rate, and so do the ADS rates: over a window ``[t_i, t_j]`` their
mean equals the rotation between the ADS attitudes at its ends,

    ā = Log(C_iᵀ C_j) / (t_j − t_i)        (C body → inertial: C(t + Δt) = C(t) Exp(ω Δt)),

up to the ADS attitude noise (``√2 σ_a / (t_j − t_i)`` per axis), the gyro's bias and its
calibration (scale factor and misalignment, 10⁻³), and the commutator terms of a rate whose
axis turns inside the window. A file written with another unit or convention breaks that
equality in a way that names the mistake:

- rates in deg/s: the rates read 180/π ≈ 57.3 times the rotation;
- times in ms: the rates read 1000 times the rotation per "second";
- a scalar-first quaternion (``w, x, y, z`` in ``ads_qx … ads_qw``): the rotation between two
  attitudes keeps its angle (the angle between two unit quaternions does not change when their
  components are permuted) but turns about another axis;
- an inertial → body quaternion (the conjugate): the rotation is seen in the other frame.

Each hypothesis is tried as a transformation of the file (:data:`HYPOTHESES`); a rate source
(gyro, ADS rate) *fits* a hypothesis when at least :data:`FIT_SHARE` of the windows agree
within :data:`NOISE_SIGMAS` times the attitude noise, plus :data:`BIAS_SIGMAS` prior bias
sigmas, plus :data:`REL_TOLERANCE` of the rotation. A file that fits as given passes;
otherwise it is refused, naming the hypothesis that fits (``rates in deg/s?``,
``scalar-first quaternion?``) or, when none does, the measured ratio. Windows whose rotation is
within the noise say nothing about a scale and are left out; a run with fewer than
:data:`MIN_WINDOWS` informative windows, under every hypothesis, cannot be checked and passes
(a file at rest gives the filter nothing to calibrate either).
``recorded.check_conventions: false`` switches the check off (a rig with a known frame offset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.core.so3 import quat_conj, quat_log, quat_mul
from qkf.transfer_alignment.recorded.columns import ADS_Q, ADS_RATE, GYRO, TIME
from qkf.transfer_alignment.recorded.reader import RecordedDataError, RecordedRun

WINDOW_S = 10.0
"""Length of a window, s: long enough that the ADS noise on the mean rotation rate
(``√2 · 3″ / 10 s ≈ 2 · 10⁻⁶ rad/s``) is far below an orbit rate (10⁻³ rad/s), short enough that
a slew of a few deg/s stays well under half a turn. Shortened for fast rotations
(:data:`MAX_WINDOW_ANGLE`), never below one row."""
MAX_WINDOW_ANGLE = 1.0
"""Largest rotation in one window, rad (the 99th percentile over the run): a rotation vector is
only defined up to a turn, so windows stay far below π."""
NOISE_SIGMAS = 20.0
"""Agreement band in sigmas of the noise the filter assumes: generous, as a data set's real ADS
noise can be several times the assumed one (the noise-mismatch studies go to 10″ against 3″)."""
BIAS_SIGMAS = 5.0
"""Agreement band for the gyro bias, in prior bias sigmas (the prior is the filter's own claim of
how large the bias may be; wider would let an orbit-rate run agree with a wrong convention)."""
REL_TOLERANCE = 0.1
"""Agreement band as a share of the rotation rate: calibration errors are 10⁻³; a gyro 10 % off
is not one this filter calibrates."""
FIT_SHARE = 0.5
"""A hypothesis fits when at least this share of the informative windows agree (windows across
a change of rate or a gap may not)."""
MIN_WINDOWS = 5
"""Fewer informative windows than this: the check cannot judge the file, which passes."""
MAX_WINDOWS = 4096
"""At most this many windows, spread over the run (the check's cost is bounded on a long file)."""
_CHUNK_ROWS = 1 << 20
"""Rows per block of the running integral of the rates (bounds the temporary memory)."""


@dataclass(frozen=True)
class Hypothesis:
    """A way the file may have been written: how to turn it into the documented convention."""

    hint: str  # "" for the file as given
    rate_scale: float = 1.0  # multiplies the rates (π/180: rates were deg/s)
    time_scale: float = 1.0  # multiplies the times (1e-3: times were ms)
    scalar_first: bool = False  # the quaternion columns hold w, x, y, z
    conjugate: bool = False  # the quaternion is inertial → body


def _hypotheses() -> tuple[Hypothesis, ...]:
    rates = ((1.0, ""), (np.pi / 180.0, "rates in deg/s? (rates are rad/s)"))
    times = ((1.0, ""), (1e-3, f"{TIME} in milliseconds? (times are seconds)"))
    quats = (
        (False, False, ""),
        (True, False, "scalar-first quaternion? (ads_qx … ads_qw are x, y, z, w: scalar last)"),
        (False, True, "inertial → body quaternion? (the ADS attitude is body → inertial)"),
        (True, True, "scalar-first, inertial → body quaternion? (x, y, z, w; body → inertial)"),
    )
    out = []
    for rs, rh in rates:
        for ts, th in times:
            for sf, cj, qh in quats:
                hint = "; ".join(h for h in (qh, rh, th) if h)
                out.append(Hypothesis(hint, rs, ts, sf, cj))
    return tuple(out)


HYPOTHESES: tuple[Hypothesis, ...] = _hypotheses()
"""Every combination of rate unit, time unit and quaternion convention; the file as given first."""


@dataclass(frozen=True)
class Windows:
    """The windows of a run: attitude rows ``start`` → ``end`` and the rates' means over them."""

    start: np.ndarray  # (W,) row index
    end: np.ndarray  # (W,) row index
    duration: np.ndarray  # (W,) in the file's time unit
    gyro: np.ndarray  # (W, 3) mean gyro reading, the file's unit
    ads_rate: np.ndarray  # (W, 3) mean ADS rate, NaN where the window has too few


def _row_angle(q: np.ndarray) -> np.ndarray:
    """Angle between consecutive unit quaternions (rows of ``q``), rad: convention-free."""
    dot = np.abs(np.einsum("ij,ij->i", q[:-1], q[1:]))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def windows(run: RecordedRun) -> Windows | None:
    """Consecutive windows of about :data:`WINDOW_S` between rows with an ADS attitude, at most
    :data:`MAX_WINDOWS` of them (None: fewer than two attitude rows)."""
    att = np.flatnonzero(run.has_attitude)
    if att.size < 2:
        return None
    t = run.t
    step = float(np.median(np.diff(t[att])))
    per_row = float(np.percentile(_row_angle(run.ads_q[att]), 99))
    rows = max(1, round(WINDOW_S / step))  # times strictly increase: step > 0
    if per_row * rows > MAX_WINDOW_ANGLE:
        rows = max(1, int(MAX_WINDOW_ANGLE / per_row))
    marks = att[::rows]
    if marks.size < 2:
        marks = att[[0, -1]]
    pick = np.arange(marks.size - 1)
    if pick.size > MAX_WINDOWS:
        pick = np.unique(np.linspace(0, marks.size - 2, MAX_WINDOWS).astype(np.int64))
    start, end = marks[pick], marks[pick + 1]
    dt_row = np.diff(t)  # row r's reading holds over [t_r, t_{r+1})
    duration = t[end] - t[start]
    gyro = _window_means(run.gyro, dt_row, start, end, duration)
    rate = _window_means(run.ads_rate, dt_row, start, end, duration)
    return Windows(start, end, duration, gyro, rate)


def _window_means(
    values: np.ndarray,
    dt_row: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    duration: np.ndarray,
) -> np.ndarray:
    """Time-weighted mean of ``values`` (n, 3) over rows ``[start, end)`` of each window; rows
    with NaN (absent) are left out, and a window less than half covered is NaN."""
    n = dt_row.size
    wanted = np.concatenate([start, end])
    integral = np.empty((wanted.size, 3))
    covered = np.empty(wanted.size)
    order = np.argsort(wanted, kind="stable")
    sorted_rows = wanted[order]
    total = np.zeros(3)
    cover = 0.0
    pos = 0
    for lo in range(0, n + 1, _CHUNK_ROWS):
        hi = min(lo + _CHUNK_ROWS, n)
        v = values[lo:hi]
        ok = np.isfinite(v).all(axis=1)
        w = np.where(ok, dt_row[lo:hi], 0.0)
        inc = np.cumsum(np.where(ok[:, None], v, 0.0) * w[:, None], axis=0)
        cinc = np.cumsum(w)
        # the integral up to row r (rows < r): r in [lo, hi]
        nxt = int(np.searchsorted(sorted_rows, hi, side="right"))
        for k in range(pos, nxt):
            r = int(sorted_rows[k])
            j = r - lo  # rows lo … r − 1 of this block
            integral[order[k]] = total + (inc[j - 1] if j > 0 else 0.0)
            covered[order[k]] = cover + (float(cinc[j - 1]) if j > 0 else 0.0)
        pos = nxt
        if hi > lo:
            total = total + inc[-1]
            cover += float(cinc[-1])
        if pos >= sorted_rows.size:
            break
    m = start.size
    covered_s = covered[m:] - covered[:m]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (integral[m:] - integral[:m]) / covered_s[:, None]
    return np.where((covered_s > 0.5 * duration)[:, None], mean, np.nan)


@dataclass(frozen=True)
class Fit:
    """How one rate source agrees with the attitudes under one hypothesis."""

    hypothesis: Hypothesis
    windows: int  # informative windows
    agree: float  # share of them that agree
    ratio: float  # median |rate| / |rotation| over them


def _rotation_rates(q: np.ndarray, w: Windows, h: Hypothesis) -> np.ndarray:
    """Mean rotation rate over each window (W, 3), rad per the file's time unit × time_scale."""
    qs, qe = q[w.start], q[w.end]
    if h.scalar_first:
        qs, qe = np.roll(qs, -1, axis=1), np.roll(qe, -1, axis=1)
    if h.conjugate:
        qs, qe = quat_conj(qs), quat_conj(qe)
    rel = quat_log(quat_mul(quat_conj(qs), qe))
    return rel / (w.duration * h.time_scale)[:, None]


def fit(
    rates: np.ndarray,
    q: np.ndarray,
    w: Windows,
    h: Hypothesis,
    sigma_att: float,
    sigma_bias: float,
) -> Fit:
    """Agreement of the mean ``rates`` (W, 3) of the windows with the attitudes ``q`` under
    ``h`` (``sigma_att`` rad: the assumed ADS noise; ``sigma_bias`` rad/s: the prior bias σ)."""
    a = _rotation_rates(q, w, h)
    g = rates * h.rate_scale
    duration = w.duration * h.time_scale
    # per window: the ADS noise on the mean rotation (√2 σ_a / T per axis, three axes) and the
    # gyro bias (three axes), each at its own multiple of σ
    noise = (
        NOISE_SIGMAS * np.sqrt(6.0) * sigma_att / duration + BIAS_SIGMAS * np.sqrt(3.0) * sigma_bias
    )
    size = np.linalg.norm(a, axis=1)
    ok = np.isfinite(g).all(axis=1) & np.isfinite(a).all(axis=1) & (size > noise)
    n = int(np.count_nonzero(ok))
    if n == 0:
        return Fit(h, 0, float("nan"), float("nan"))
    miss = np.linalg.norm(g[ok] - a[ok], axis=1)
    agree = float(np.mean(miss <= noise[ok] + REL_TOLERANCE * size[ok]))
    ratio = float(np.median(np.linalg.norm(g[ok], axis=1) / size[ok]))
    return Fit(h, n, agree, ratio)


def check_conventions(run: RecordedRun, sigma_att: float, sigma_bias: float) -> None:
    """Refuse ``run`` (:class:`RecordedDataError`) when its gyro or ADS rates disagree with the
    rotation of its ADS attitudes (module doc): ``sigma_att`` rad, the ADS attitude noise the
    filter assumes; ``sigma_bias`` rad/s, its prior bias σ."""
    w = windows(run)
    if w is None:
        return
    for name, columns, rates in (("gyro", GYRO, w.gyro), ("ADS rate", ADS_RATE, w.ads_rate)):
        as_given = fit(rates, run.ads_q, w, HYPOTHESES[0], sigma_att, sigma_bias)
        if as_given.windows >= MIN_WINDOWS and as_given.agree >= FIT_SHARE:
            continue
        # the file as given disagrees, or says nothing (a run at rest; or times in ms, whose
        # windows are 1000 times too long): does another reading fit?
        fits = [fit(rates, run.ads_q, w, h, sigma_att, sigma_bias) for h in HYPOTHESES[1:]]
        good = [f for f in fits if f.windows >= MIN_WINDOWS and f.agree >= FIT_SHARE]
        if not good and as_given.windows < MIN_WINDOWS:
            continue  # too little rotation to judge
        cols = f"{', '.join(columns)} against {', '.join(ADS_Q)}"
        said = (
            f"the {name} agrees with the rotation of the ADS attitudes in {as_given.agree:.0%} "
            f"of {as_given.windows} windows of about {WINDOW_S:g} s (median |{name}| / "
            f"|rotation| = {as_given.ratio:.4g})"
            if as_given.windows
            else "as given, the ADS attitudes show no rotation above their noise"
        )
        if good:
            best = max(good, key=lambda f: (f.agree, f.windows))
            raise RecordedDataError(
                f"{run.path}: columns {cols}: {said}. {best.hypothesis.hint} Read that way, "
                f"{best.agree:.0%} of {best.windows} windows agree (docs/recorded_data.md, "
                '"Units and conventions"; recorded.check_conventions: false skips this check)'
            )
        raise RecordedDataError(
            f"{run.path}: columns {cols}: {said}, and no unit or quaternion convention tried "
            "explains it (deg/s, ms, scalar-first, inertial → body): the rates and the attitudes "
            "do not describe the same motion. If the frames differ on purpose, set "
            'recorded.check_conventions: false (docs/recorded_data.md, "Units and conventions")'
        )
