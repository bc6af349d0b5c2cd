r"""What the benchmark judges and the truth-tuned methods tune for (docs/methods.md, "Judging").

The whole-state metric ``state_settled`` of one trial::

    state_settled = sqrt( mean over settled epochs k and states i of (e_{k,i} / w_i)² )

with ``e`` the estimation error (:func:`~qkf.transfer_alignment.metrics.state_errors`), the
trial's own settled window and ``w_i`` a fixed weight per state: the CRLB of state ``i`` at the
end of the run along the trial's own trajectory (:mod:`qkf.transfer_alignment.settled`;
:func:`state_weights` is the nominal schedule's, for recorded runs and the reward). It is
dimensionless ("RMS in units of the final bound"); a method that trades one group for another
shows, because every state counts in units of what it can be known to. The group metrics
(``ma_urad_settled`` …) are the RMS of one group's errors.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.metrics import state_errors
from qkf.transfer_alignment.model import CALIB
from qkf.transfer_alignment.scenario import ScenarioData
from qkf.transfer_alignment.settled import SettledWindows, settled_windows
from qkf.transfer_alignment.states import GROUPS

STATE_METRIC = "state_settled"

METRIC_STATES: dict[str, slice] = {
    "ma_urad_settled": GROUPS["ma_urad"],
    "sf_ppm_settled": GROUPS["sf_ppm"],
    "calibration_settled": CALIB,
}
"""The states of the group criteria a truth-tuned method may be tuned for (SI RMS)."""


def state_weights(cfg: Config) -> np.ndarray:
    """The per-state weights of ``state_settled`` (15,), SI: the nominal CRLB (the scenario's
    fixed schedule, nominal truth) at the last epoch. Cached per scenario and filter."""
    key = cfg.model_copy(update={"adaptive": type(cfg.adaptive)(), "run": type(cfg.run)()})
    return _weights(key.model_dump_json()).copy()


@lru_cache(maxsize=64)
def _weights(cfg_json: str) -> np.ndarray:
    cfg = Config.model_validate_json(cfg_json)
    w = crlb(cfg).bound[-1]
    if not np.all(np.isfinite(w) & (w > 0.0)):
        raise ValueError("the nominal CRLB at the end of the run is not finite and positive")
    return w


def trial_scores(
    err: np.ndarray, windows: SettledWindows, metric: str = STATE_METRIC
) -> np.ndarray:
    """Per trial, the settled-window RMS of ``metric`` (B,): ``err`` (B, N, 15) SI errors,
    ``windows`` the trials' settled windows and weights
    (:func:`~qkf.transfer_alignment.settled.settled_windows`).

    ``state_settled`` is dimensionless (module docstring); the group criteria are SI. NaN
    for a trial whose errors are not finite over its window.
    """
    if metric == STATE_METRIC:
        sq = (err / windows.weights[:, None, :]) ** 2
    elif metric in METRIC_STATES:
        sq = err[..., METRIC_STATES[metric]] ** 2
    else:
        known = ", ".join([STATE_METRIC, *METRIC_STATES])
        raise ValueError(f"unknown metric {metric!r}; known: {known}")
    mask = windows.mask(err.shape[1])
    # masked epochs are left out, not multiplied by 0 (a NaN before the window stays out)
    total = np.sum(np.where(mask[..., None], sq, 0.0), axis=(1, 2))
    return np.sqrt(total / (mask.sum(axis=1) * sq.shape[-1]))


def estimate_scores(
    cfg: Config, est: np.ndarray, data: ScenarioData, metric: str = STATE_METRIC
) -> np.ndarray:
    """:func:`trial_scores` of estimates ``est`` (B, N, 16) of ``data``'s trials, simulated
    from ``cfg``."""
    err = state_errors(est, data.q_true, data.bias, data.calib)
    return trial_scores(err, settled_windows(cfg, data), metric)


def pooled(scores: np.ndarray, diverged: np.ndarray | None = None) -> float:
    """RMS over trials of per-trial scores; ``inf`` if any trial diverged or is not finite
    (a tuning criterion never prefers a setting that loses a trial)."""
    scores = np.asarray(scores, dtype=float)
    if (diverged is not None and np.any(diverged)) or not np.all(np.isfinite(scores)):
        return float("inf")
    return float(np.sqrt(np.mean(scores**2)))
