r"""A schedule of the filter's moves, run (docs/methods.md, "Moves").

The moves of :mod:`qkf.transfer_alignment.moves` (κ, the attitude and bias process-noise
factors, the assumed ADS σ factor, a calibration reset) decided once per period of ``period``
epochs, per trial. :func:`run_moves` runs the filter with them: before period ``p`` the moves
``schedule.at(p)`` are applied (:func:`~qkf.transfer_alignment.moves.apply_moves`: the reset
re-opens the calibration covariance at the period's first epoch), then the period is filtered.
What a v4 policy's episodes do (:mod:`envs.transfer_alignment.episodes`), and what the
hindsight over the moves (:mod:`.hindsight_moves`) searches; with nominal moves and κ alone it
is :func:`~.oracle.run_schedule` of the same κ, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import EpochRecords, MethodOutput, new_filter, per_epoch
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder, step_recording
from qkf.transfer_alignment.moves import Moves, apply_moves
from qkf.transfer_alignment.scenario import ScenarioData

MOVE_FIELDS = ("kappa", "q_att", "q_bias", "r_scale", "reset")
"""The fields of a schedule, in :class:`~qkf.transfer_alignment.moves.Moves` order."""


@dataclass(frozen=True)
class MoveSchedule:
    """Moves per trial and period: each field (B, T), ``period`` epochs per period."""

    period: int
    kappa: np.ndarray
    q_att: np.ndarray
    q_bias: np.ndarray
    r_scale: np.ndarray
    reset: np.ndarray

    @classmethod
    def from_moves(cls, period: int, moves: list[Moves]) -> MoveSchedule:
        """The schedule of one :class:`Moves` (B,) per period."""
        cols = [np.stack([m.fields()[i] for m in moves], axis=1) for i in range(5)]
        return cls(period, *cols)

    @classmethod
    def nominal(cls, period: int, kappa: np.ndarray) -> MoveSchedule:
        """κ (B, T) and no other move."""
        kappa = np.asarray(kappa, dtype=float)
        ones = np.ones(kappa.shape)
        return cls(period, kappa, ones, ones.copy(), ones.copy(), np.zeros(kappa.shape))

    def fields(self) -> tuple[np.ndarray, ...]:
        return (self.kappa, self.q_att, self.q_bias, self.r_scale, self.reset)

    def at(self, p: int, rows: np.ndarray | slice = slice(None)) -> Moves:
        """The moves of period ``p`` (of trials ``rows``)."""
        return Moves(*(np.asarray(f[rows, p], dtype=float) for f in self.fields()))

    def as_logs(self) -> dict[str, np.ndarray]:
        """The schedule as method logs (``moves_kappa`` … (B, T)): datasets read them."""
        return {f"moves_{n}": f for n, f in zip(MOVE_FIELDS, self.fields(), strict=True)}


def run_moves(cfg: Config, data: ScenarioData, schedule: MoveSchedule) -> MethodOutput:
    """The filter with ``schedule``'s moves (module docstring); κ per epoch, the covariance at
    the sampled epochs and the schedule in ``logs``."""
    kf = new_filter(cfg, data)
    cov = CovarianceRecorder(cfg, data.n_trials)
    epochs = EpochRecords(data.n_trials, data.n_epochs)
    est = np.empty((data.n_trials, data.n_epochs, 16))
    p = schedule.period
    for i, k0 in enumerate(range(0, data.n_epochs, p)):
        k1 = min(data.n_epochs, k0 + p)
        kappa = apply_moves(kf, schedule.at(i))
        rec = step_recording(kf, data, k0, k1, kappa, cov)
        est[:, k0:k1] = rec.est
        epochs.put(k0, rec)
    out = MethodOutput(
        est=est,
        diverged=kf.diverged.copy(),
        kappa=per_epoch(schedule.kappa, p, data.n_epochs),
        cov=cov.cov,
        logs=schedule.as_logs(),
    )
    return epochs.attach(out)
