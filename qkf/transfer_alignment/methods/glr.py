r"""GLR reset: a CUSUM change detector on the innovations that re-opens the calibration
covariance on alarm (docs/methods.md, "GLR reset").

The textbook handling of an abrupt change in a Kalman filter (Willsky & Jones 1976; Basseville
& Nikiforov 1993, the CUSUM): the filter runs with a constant process-noise factor
``κ = adaptive.glr.kappa``, and a sequential test watches its innovations. While the model
holds, the innovation ``ν_k`` (m rows) of epoch k is ``N(0, S_k)``; a calibration jump makes it
larger than ``S_k`` says. The test is between "no change", ``ν_k ~ N(0, S_k)``, and "a change",
``ν_k ~ N(0, λ S_k)`` with ``λ = adaptive.glr.inflation > 1``. The log-likelihood ratio of one
measurement epoch, with ``NIS_k = ν_kᵀ S_k⁻¹ ν_k`` (all rows), is::

    ℓ_k = ln N(ν_k; 0, λ S_k) − ln N(ν_k; 0, S_k) = ½ [(1 − 1/λ) NIS_k − m ln λ]

(0 at an epoch without a measurement), and Page's CUSUM accumulates it::

    g_k = max(0, g_{k−1} + ℓ_k),   g_0 = 0,        alarm at k  ⇔  g_k > h

with ``h = adaptive.glr.threshold``. Under no change ``E[ℓ] = ½ m (1 − 1/λ − ln λ) < 0`` (as
``1 − 1/λ < ln λ`` for λ > 1), so ``g`` keeps returning to 0, and the mean time between false
alarms grows like ``e^h``; under a change of exactly λ, ``E[ℓ] = ½ m (λ − 1 − ln λ) > 0``.

At every alarm the detector restarts (``g ← 0``). If the last re-opening is at least
``quiet_s`` ago (or there was none), the alarm also re-opens the calibration block of the
covariance::

    P_ii ← P_ii + σ_r²,   σ_r = reset_ppm · 10⁻⁶ (rad or 1),   i = the 9 calibration terms

and leaves the rest of ``P`` as it is. Adding a positive diagonal matrix keeps ``P`` symmetric
positive definite. The quiet time is there because one jump can raise an alarm at each rotation
axis that makes another part of it observable; re-opening at each of them would throw away
what the previous axis taught (at the defaults, every measured jump raised one alarm).

**Timing (latency).** The test is decided per epoch. The compiled filter's call for epoch k
does the update with ``ν_k`` and the propagation to k + 1, so the alarm raised by ``ν_k``
re-opens the predicted covariance ``P⁻_{k+1}``: the very next update uses it. Beyond the
detection delay of the CUSUM itself there is no latency. The filter is run speculatively in
blocks of :data:`BLOCK` epochs (a compiled call per epoch is slow, much slower when the cores
are busy): the statistic is run through the block's NIS epoch by epoch, and if a re-opening
falls inside the block the filter is restored to the block's start and run again to the end of
that epoch only, then re-opened. The result is that of stepping one epoch at a time, bit for
bit (a test checks it), at the cost of about one extra block per re-opening.

Batched over trials: each trial has its own statistic, alarms and re-openings; a re-opening
changes only the covariance of its own trial (the other trials' ``P`` is not touched, not even
by a rounding). A diverged trial has no finite NIS, so ``ℓ = 0`` and it never alarms.

Output: the filter's estimates and covariance, κ (constant), and logs ``cusum`` (B, N), the
statistic ``g_k`` before an alarm's restart, ``alarm`` and ``reopen`` (B, N) bool.
"""

from __future__ import annotations

import numpy as np

from qkf.transfer_alignment.adaptive import GlrConfig
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import (
    EpochRecords,
    MethodOutput,
    new_filter,
    uses_settings,
)
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.moves import reopen_calibration
from qkf.transfer_alignment.scenario import ScenarioData

BLOCK = 100
"""Epochs per speculative filter call of :func:`glr_filter` (a speed setting only)."""


def log_likelihood_ratio(nis: np.ndarray, n_meas: int, inflation: float) -> np.ndarray:
    """``ℓ = ½ [(1 − 1/λ) NIS − m ln λ]`` per epoch (any shape); 0 where NIS is not finite (no
    measurement, or a diverged trial). Dimensionless (nats)."""
    ok = np.isfinite(nis)
    ell = 0.5 * ((1.0 - 1.0 / inflation) * np.where(ok, nis, 0.0) - n_meas * np.log(inflation))
    return np.where(ok, ell, 0.0)


def cusum_step(g_prev: np.ndarray, ell: np.ndarray) -> np.ndarray:
    """Page's recursion ``g_k = max(0, g_{k−1} + ℓ_k)``."""
    return np.maximum(0.0, g_prev + ell)


class GlrPeriodDecision:
    """The GLR rule decided once per period of N runs, for the environments' residual controls
    (``base="glr"``, docs/environment.md, "Controls"): the CUSUM runs through the period's
    epochs as in :func:`glr_filter`, and an alarm that passes the quiet time re-opens the
    calibration block when the *next* period starts (up to one period later than the method,
    which re-opens at the epoch after the alarm). ``__call__(nis (N, P), t_end (N,))`` returns
    which runs re-open; ``reset(rows)`` starts runs anew."""

    def __init__(self, settings: GlrConfig, n: int, n_meas: int) -> None:
        self.settings = settings
        self.n_meas = n_meas
        self.g = np.zeros(n)
        self.last_reopen = np.full(n, -np.inf)

    def reset(self, rows: np.ndarray) -> None:
        self.g[rows] = 0.0
        self.last_reopen[rows] = -np.inf

    def __call__(self, nis: np.ndarray, t_end: np.ndarray) -> np.ndarray:
        prm = self.settings
        ell = log_likelihood_ratio(nis, self.n_meas, prm.inflation)  # (N, P), 0 where no NIS
        reopen = np.zeros(self.g.size, dtype=bool)
        for k in range(ell.shape[1]):
            self.g = cusum_step(self.g, ell[:, k])
            alarm = self.g > prm.threshold
            self.g = np.where(alarm, 0.0, self.g)  # the detector restarts after every alarm
            reopen |= alarm & (t_end - self.last_reopen >= prm.quiet_s - 1e-9) & ~reopen
        self.last_reopen = np.where(reopen, t_end, self.last_reopen)
        return reopen


def glr_filter(cfg: Config, data: ScenarioData, prm: GlrConfig, block: int = BLOCK) -> MethodOutput:
    """The filter with constant κ and the CUSUM reset rule (module docstring), batched over
    trials, with the settings ``prm`` (:class:`GlrConfig`). ``block``: epochs per speculative
    filter call (any value gives the same result, bit for bit)."""
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    b, n = data.n_trials, data.n_epochs
    m = kf.params.n_meas
    sigma = prm.reset_ppm * 1e-6  # ppm or µrad → SI
    g = np.zeros(b)
    last_reopen = np.full(b, -np.inf)  # time of the last re-opening, s
    est = np.empty((b, n, 16))
    epochs = EpochRecords(b, n)
    g_log = np.empty((b, n))
    alarms = np.zeros((b, n), dtype=bool)
    reopened = np.zeros((b, n), dtype=bool)
    k0 = 0
    while k0 < n:
        k1 = min(n, k0 + block)
        saved = kf.copy()
        rec = step_recording(kf, data, k0, k1, prm.kappa, cov)
        ell = log_likelihood_ratio(rec.nis, m, prm.inflation)  # (B, k1 − k0)
        stop, reopen = k1, np.zeros(b, dtype=bool)
        for k in range(k0, k1):
            g = cusum_step(g, ell[:, k - k0])
            g_log[:, k] = g
            alarm = g > prm.threshold
            if not np.any(alarm):
                continue
            # quiet time with a tolerance: t is a multiple of dt, in floating point
            reopen = alarm & (data.t[k] - last_reopen >= prm.quiet_s - 1e-9)
            last_reopen = np.where(reopen, data.t[k], last_reopen)
            g = np.where(alarm, 0.0, g)  # the detector restarts after every alarm
            alarms[:, k] = alarm
            reopened[:, k] = reopen
            if np.any(reopen):
                stop = k + 1
                break
        if stop < k1:
            # the filter ran past a re-opening: take it back and run it to the end of epoch k
            # only (the covariance samples after it are recorded again when it gets there)
            kf.copy_state_from(saved)
            rec = step_recording(kf, data, k0, stop, prm.kappa, cov)
        est[:, k0:stop] = rec.est[:, : stop - k0]
        epochs.put(k0, rec)
        reopen_calibration(kf, reopen, sigma)  # acts on P⁻_{k+1}: the next update uses it
        k0 = stop
    per_trial = reopened.sum() / b
    note = (
        f"CUSUM of the innovation log-likelihood ratio (λ = {prm.inflation:g}, h = "
        f"{prm.threshold:g}); {per_trial:.2g} re-openings of σ = {prm.reset_ppm:g} ppm/µrad per "
        f"trial (quiet {prm.quiet_s:g} s); κ = {prm.kappa:.3g}"
    )
    out = MethodOutput(
        est=est,
        diverged=kf.diverged.copy(),
        kappa=np.full((b, n), prm.kappa),
        logs={"cusum": g_log, "alarm": alarms, "reopen": reopened},
        notes={"glr": note},
        cov=cov.cov,
    )
    return epochs.attach(out)


@uses_settings("glr", GlrConfig)
def run_glr(cfg: Config, data: ScenarioData) -> MethodOutput:
    """The ``glr`` method: :func:`glr_filter` with the config's settings (``adaptive.glr``)."""
    return glr_filter(cfg, data, cfg.adaptive.glr)
