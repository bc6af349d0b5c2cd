"""The covariance a method reports, sampled at a few epochs, so the benchmark can judge it by NEES.

A method's covariance is judged against its own errors (docs/methods.md, "Consistency"): at the
epochs of :func:`covariance_epochs` (every ``run.nees_every_s``) the method reports the 15 × 15
error covariance it believes, ``P = E[δx δxᵀ]`` with ``δx = [δθ (rad), δb (rad/s), δp]`` defined
as in :func:`qkf.transfer_alignment.metrics.state_errors`. Sampling keeps the record small: the
full (B, N, 15, 15) history of a 900 s run at 10 Hz would take 1.6 GB per 100 trials.

:class:`CovarianceRecorder` collects those samples; :func:`step_recording` runs a filter over a
block of epochs and records its covariance at the sampled epochs inside the block (the kernel
records the a-posteriori covariance of every epoch it is asked to, so the block is split there).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.filter import (
    FilterRecord,
    SensorData,
    TransferAlignmentKF,
    expand_kappa,
)
from qkf.transfer_alignment.params import n_epochs

N_STATES = 15


def covariance_epochs(cfg: Config) -> np.ndarray:
    """Epoch indices at which methods report their covariance: ``t = j · run.nees_every_s``,
    ``j = 1, 2, …`` (rounded to the filter's epochs), and never the initial epoch."""
    n = n_epochs(cfg.scenario)
    step = max(1, round(cfg.run.nees_every_s / cfg.scenario.dt_s))
    return np.arange(step, n, step, dtype=np.int64)


class CovarianceRecorder:
    """Collects a method's covariance (B, M, 15, 15) at the epochs of :func:`covariance_epochs`.

    Unrecorded samples stay NaN (the benchmark leaves them out of the NEES).
    """

    def __init__(self, cfg: Config, n_trials: int) -> None:
        self.epochs = covariance_epochs(cfg)
        self._slot = {int(k): j for j, k in enumerate(self.epochs)}
        self.cov = np.full((n_trials, self.epochs.size, N_STATES, N_STATES), np.nan)

    def take(self, k: int, cov: np.ndarray) -> None:
        """Store the covariance (B, 15, 15) of epoch ``k`` if it is sampled."""
        j = self._slot.get(int(k))
        if j is not None:
            self.cov[:, j] = cov

    def sampled_in(self, k0: int, k1: int) -> np.ndarray:
        """The sampled epochs in ``[k0, k1)``."""
        lo, hi = np.searchsorted(self.epochs, [k0, k1])
        return self.epochs[lo:hi]


def step_recording(
    kf: TransferAlignmentKF,
    data: SensorData,
    k0: int,
    k1: int,
    kappa: float | np.ndarray,
    recorder: CovarianceRecorder | None,
) -> FilterRecord:
    """:meth:`TransferAlignmentKF.step_data` over ``[k0, k1)`` that also hands the a-posteriori
    covariance of every sampled epoch inside the block to ``recorder`` (see :func:`step_arrays`).
    """
    sl = slice(k0, k1)
    return step_arrays(
        kf, data.gyro[:, sl], data.ads_q[:, sl], data.ads_rate[:, sl], data.has_meas[..., sl],
        kappa, k0, recorder,
    )  # fmt: skip


def step_arrays(
    kf: TransferAlignmentKF,
    gyro: np.ndarray,
    ads_q: np.ndarray,
    ads_rate: np.ndarray,
    has_meas: np.ndarray,
    kappa: float | np.ndarray,
    epoch0: int,
    recorder: CovarianceRecorder | None,
) -> FilterRecord:
    """:meth:`TransferAlignmentKF.step` on a block whose first epoch is ``epoch0`` of the run,
    handing the a-posteriori covariance of the sampled epochs inside it to ``recorder``.

    The block is run in pieces that end on the sampled epochs, the last epoch of each piece with
    its covariance recorded; the estimates are identical to those of one call.
    """
    n = gyro.shape[1]
    marks = (
        np.empty(0, dtype=np.int64) if recorder is None else recorder.sampled_in(epoch0, epoch0 + n)
    )
    if marks.size == 0:
        return kf.step(gyro, ads_q, ads_rate, has_meas, kappa)
    assert recorder is not None
    kap = expand_kappa(kappa, kf.n_trials, n)  # (B, n, 9): sliced per piece below
    meas = np.broadcast_to(np.asarray(has_meas, dtype=bool), (kf.n_trials, n))

    out: dict[str, np.ndarray] = {}

    def piece(a: int, b: int, record: bool) -> FilterRecord:
        sl = slice(a, b)
        rec = kf.step(gyro[:, sl], ads_q[:, sl], ads_rate[:, sl], meas[:, sl], kap[:, sl], record)
        # each piece goes straight into the block's record: one copy of the block in memory,
        # not the pieces and their concatenation (a day at 10 Hz is 0.4 GB per copy)
        for f in dataclasses.fields(FilterRecord):
            if f.name == "cov":
                continue
            value = getattr(rec, f.name)
            if f.name not in out:
                out[f.name] = np.empty((value.shape[0], n, *value.shape[2:]), value.dtype)
            out[f.name][:, sl] = value
        return rec

    start = 0
    for k in [*(marks - epoch0).tolist(), n]:
        if k > start:  # the epochs before the mark, without covariance
            piece(start, k, False)
        if k < n:  # the mark itself
            rec = piece(k, k + 1, True)
            assert rec.cov is not None
            recorder.take(epoch0 + k, rec.cov[:, 0])
            start = k + 1
    return FilterRecord(cov=None, **out)
