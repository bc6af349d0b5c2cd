"""Errors of transfer-alignment estimates against the truth, and their summaries (SI in,
display units out). Generic statistics (NEES, running sums) are in :mod:`qkf.core.stats`.

Error convention as the filter's (docs/models.md): ``δθ = Log(Ĉᵀ C_true)``, ``Δb = b − b̂``,
``Δp = p − p̂``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

import qkf.core.jit  # noqa: F401  (binds compiled callees locally: docs/performance.md)
from qkf.core.jit import kernel_array
from qkf.core.quat import attitude_error_into
from qkf.transfer_alignment.states import GROUPS, N_STATES


def state_errors(
    est: np.ndarray, q_true: np.ndarray, bias: np.ndarray, calib: np.ndarray
) -> np.ndarray:
    """True estimation errors (B, n, 15), SI.

    ``est`` (B, n, 16) = [q̂, b̂, p̂]; ``q_true`` (n, 4) or (B, n, 4); ``bias`` (B, n, 3);
    ``calib`` (B, n, 9). The attitude error is NaN where either quaternion is not finite (a
    diverged estimate, or no truth in recorded data).
    """
    b, n = est.shape[:2]
    if q_true.ndim == 2:
        q_true = np.broadcast_to(q_true, (b, n, 4))
    for name, arr, width in (("est", est, 16), ("q_true", q_true, 4), ("bias", bias, 3),
                             ("calib", calib, 9)):  # fmt: skip
        if arr.shape != (b, n, width):
            raise ValueError(f"{name} has shape {arr.shape}, expected ({b}, {n}, {width})")
    err = np.empty((b, n, N_STATES))
    # one array type whatever the views given: each other type compiles the routine again
    est, q_true, bias, calib = (kernel_array(a, float, a.shape) for a in (est, q_true, bias, calib))
    _state_errors_into(est, q_true, bias, calib, err)
    return err


@nb.njit(cache=True)
def _state_errors_into(
    est: np.ndarray, q_true: np.ndarray, bias: np.ndarray, calib: np.ndarray, err: np.ndarray
) -> None:
    """:func:`state_errors` into ``err``, compiled: ``δθ = Log(q̂* ⊗ q)`` of the normalised
    quaternions (:func:`~qkf.core.quat.attitude_error_into`), ``Δb = b − b̂``, ``Δp = p − p̂``.

    One call instead of a dozen numpy ones: for a single environment's decision period they
    cost more than the arithmetic (docs/performance.md). Compiled without fast-math, as the
    rotation core, so the numbers are those of the numpy expressions.
    """
    for i in range(est.shape[0]):
        attitude_error_into(est[i, :, 0:4], q_true[i], err[i, :, 0:3])
        for k in range(est.shape[1]):
            for j in range(3):
                err[i, k, 3 + j] = bias[i, k, j] - est[i, k, 4 + j]
            for j in range(9):
                err[i, k, 6 + j] = calib[i, k, j] - est[i, k, 7 + j]


def group_rms(ms_per_state: np.ndarray) -> dict[str, np.ndarray]:
    """Root of the mean over each group's states of a mean-square array (..., 15)."""
    return {g: np.sqrt(np.mean(ms_per_state[..., sl], axis=-1)) for g, sl in GROUPS.items()}


WINDOWS: tuple[str, ...] = ("final", "avg", "settled")
"""Time windows of the summary metrics: the last 20 % of the run, the whole run, and from
``run.settled_s`` to the end (where adaptation is judged: docs/methods.md)."""

STATE_SETTLED = "state_settled"
"""The whole-state metric (:mod:`qkf.transfer_alignment.judging`): dimensionless, each state's
settled error in units of its final nominal CRLB."""

METRIC_COLUMNS: tuple[str, ...] = (
    *(f"{g}_{w}" for g in GROUPS for w in WINDOWS),
    STATE_SETTLED,
)
"""Summary metrics in column order: ``<group>_<window>``, then ``state_settled``."""

FINAL_FRACTION = 0.2


def window_masks(t: np.ndarray, settled_s: float) -> dict[str, np.ndarray]:
    """Epoch masks of the windows (N,) bool; a window is never empty (at least the last epoch)."""
    n = t.size
    start = min(n - 1, int(np.floor(n * (1.0 - FINAL_FRACTION))))
    final = np.arange(n) >= start
    settled = t >= settled_s - 1e-9
    if not settled.any():
        settled = np.arange(n) == n - 1
    return {"final": final, "avg": np.ones(n, dtype=bool), "settled": settled}


def trial_mean_squares(
    err: np.ndarray, t: np.ndarray, settled_first: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Per trial, the mean square of each metric (B, K) in :data:`METRIC_COLUMNS` order: over
    the window's epochs and the group's components; ``state_settled`` over the settled epochs
    and all 15 states of ``err / weights``. ``settled_first`` (B,): each trial's first settled
    epoch (:class:`~qkf.transfer_alignment.settled.SettledWindows`); ``err`` (B, N, 15) and
    ``weights`` (B, 15) or (15,) in the same units (any)."""
    n = t.size
    masks = window_masks(t, float(t[-1]) if n else 0.0)
    settled = np.arange(n)[None, :] >= np.asarray(settled_first)[:, None]  # (B, N)
    count = settled.sum(axis=1)
    sq = err * err
    cols = []
    for sl in GROUPS.values():
        group = np.mean(sq[..., sl], axis=-1)  # (B, N)
        cols += [np.mean(group[:, masks["final"]], axis=1), np.mean(group, axis=1)]
        cols.append(np.sum(np.where(settled, group, 0.0), axis=1) / count)
    w = np.broadcast_to(weights, (err.shape[0], err.shape[-1]))
    scaled = np.mean((err / w[:, None, :]) ** 2, axis=2)
    cols.append(np.sum(np.where(settled, scaled, 0.0), axis=1) / count)
    return np.stack(cols, axis=1)


def summarize(
    rms: np.ndarray, t: np.ndarray, settled_s: float, weights: np.ndarray | None = None
) -> dict[str, float]:
    """The metrics of an RMS-over-trials curve (N, 15) (e.g. the CRLB): root mean square over
    each window's epochs and the group's components; ``state_settled`` with ``weights`` (15,)
    in the units of ``rms`` (NaN without them)."""
    masks = window_masks(t, settled_s)
    ms = rms * rms
    out = {
        f"{g}_{w}": float(np.sqrt(np.mean(ms[masks[w]][:, sl])))
        for g, sl in GROUPS.items()
        for w in WINDOWS
    }
    out[STATE_SETTLED] = (
        float("nan")
        if weights is None
        else float(np.sqrt(np.mean((rms[masks["settled"]] / weights) ** 2)))
    )
    return out


def recovery_times(
    rms: np.ndarray, t: np.ndarray, jump_s: float, settled_s: float, factor: float = 1.5
) -> dict[str, float]:
    """Per group, the time from a calibration jump at ``jump_s`` until the group RMS (over
    trials, (N, 15)) is back within ``factor`` × its settled pre-jump level (RMS over
    ``[settled_s, jump_s)``); NaN when there is no settled stretch before the jump or the RMS
    never comes back."""
    out: dict[str, float] = {}
    before = (t >= settled_s - 1e-9) & (t < jump_s - 1e-9)
    after = t >= jump_s - 1e-9
    for g, sl in GROUPS.items():
        curve = np.sqrt(np.mean(rms[:, sl] ** 2, axis=-1))
        if not before.any() or not after.any():
            out[g] = float("nan")
            continue
        level = np.sqrt(np.mean(curve[before] ** 2))
        back = np.flatnonzero(after & (curve <= factor * level))
        out[g] = float(t[back[0]] - jump_s) if back.size else float("nan")
    return out
