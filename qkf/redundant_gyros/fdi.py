"""Fault detection, isolation and reconfiguration per epoch: three-cross and GLT side by side
(docs/redundant_gyros.md, "FDI").

The readings are compensated with the nominal errors, both detectors run on them, and the
output rate comes from the model that leaves out the gyro isolated by the detector chosen in
``fdi.reconfigure_by`` (three-cross, as the paper, by default), or from the weighted fusion of
the three models when nothing is isolated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.redundant_gyros.config import FdiConfig
from qkf.redundant_gyros.geometry import GyroUnit
from qkf.redundant_gyros.parity import GltDetector, GltResult
from qkf.redundant_gyros.threecross import NO_GYRO, ThreeCrossDetector

FUSION = "fusion"


@dataclass(frozen=True)
class Detectors:
    """The detectors of one unit, built once (the three-cross null probabilities take a
    Monte Carlo run) and applied to any number of trials."""

    unit: GyroUnit
    threecross: ThreeCrossDetector
    glt: GltDetector  # the configured window
    glt_epoch: GltDetector  # window 1: the classic per-epoch test
    reconfigure_by: str

    @classmethod
    def build(cls, unit: GyroUnit, cfg: FdiConfig) -> Detectors:
        tc = cfg.threecross
        return cls(
            unit=unit,
            threecross=ThreeCrossDetector.build(
                unit, tc.window_epochs, cfg.false_alarm_probability, tc.null_samples
            ),
            glt=GltDetector(unit, cfg.glt_window_epochs, cfg.false_alarm_probability),
            glt_epoch=GltDetector(unit, 1, cfg.false_alarm_probability),
            reconfigure_by=cfg.reconfigure_by,
        )

    @property
    def model_names(self) -> list[str]:
        """Output model per index: index i leaves gyro i out; index n is the fusion."""
        return [name for name, _ in self.unit.exclusion] + [FUSION]


@dataclass(frozen=True)
class FdiResult:
    feature: np.ndarray  # (B, E)
    isolated_threecross: np.ndarray  # (B, E) gyro index or NO_GYRO
    glt: GltResult  # configured window
    model: np.ndarray  # (B, E) index into Detectors.model_names
    rate: np.ndarray  # (B, E, 3) reconstructed body rate, deg/s


def reconstruct(
    unit: GyroUnit, y: np.ndarray, isolated: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Output model index and rate (deg/s) per epoch from compensated readings ``y`` (B, E, n)
    and the isolated gyro per epoch."""
    model = np.where(isolated == NO_GYRO, unit.n, isolated).astype(np.int16)
    rate = np.full((*y.shape[:-1], 3), np.nan)
    mats = [m for _, m in unit.exclusion] + [unit.fusion]
    for idx, mat in enumerate(mats):
        mask = model == idx
        if mask.any():
            rate[mask] = y[mask] @ mat.T
    return model, rate


def run_fdi(det: Detectors, meas: np.ndarray) -> FdiResult:
    """Both detectors and the reconfigured rate for raw readings ``meas`` (B, E, n), deg/s."""
    y = det.unit.compensate(meas)
    feature, iso_tc = det.threecross.isolate(y)
    glt = det.glt.test(y)
    chosen = iso_tc if det.reconfigure_by == "threecross" else glt.isolated
    model, rate = reconstruct(det.unit, y, chosen)
    return FdiResult(feature, iso_tc, glt, model, rate)
