"""``qkf gyros run`` as a library call: readings → FDI → the gyro to calibrate → UKF
(docs/redundant_gyros.md, "Run").

Which gyro is calibrated, from when, against which triad:

* ``calibration.gyro`` if set, else the gyro that ``calibration.source`` (three-cross or GLT)
  isolates most often; nothing is calibrated when nothing is ever isolated;
* from ``calibration.start_s`` if set, else from the first epoch that gyro is isolated;
* against ``calibration.triad`` if set, else the best-conditioned triad of the other gyros.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.fdi import Detectors, FdiResult, run_fdi
from qkf.redundant_gyros.geometry import GyroUnit, build_unit
from qkf.redundant_gyros.scenario import GyroData, epochs, first_epoch, simulate, trial_onset
from qkf.redundant_gyros.threecross import NO_GYRO
from qkf.redundant_gyros.ukf import (
    CalibrationRecord,
    UkfSetup,
    calibrate,
    make_setup,
)


@dataclass(frozen=True)
class Target:
    """The calibration to run: gyro index, first epoch, triad, and why."""

    gyro: int
    start: int
    triad: tuple[int, int, int] | None
    reason: str


def _triad(cfg: GyrosConfig, unit: GyroUnit) -> tuple[int, int, int] | None:
    tri = cfg.calibration.triad
    if tri is None:
        return None
    return (unit.index(tri[0]), unit.index(tri[1]), unit.index(tri[2]))


def choose_target(cfg: GyrosConfig, unit: GyroUnit, fdi: FdiResult, t: np.ndarray) -> Target | None:
    """The calibration of one trial (row 0 of ``fdi``), as the module docstring says."""
    cal = cfg.calibration
    iso = (fdi.isolated_threecross if cal.source == "threecross" else fdi.glt.isolated)[0]
    if cal.gyro is not None:
        gyro, reason = unit.index(cal.gyro), "configured"
    else:
        found = iso[iso != NO_GYRO]
        if found.size == 0:
            return None
        gyro = int(np.bincount(found, minlength=unit.n).argmax())
        reason = f"isolated most often by {cal.source}"
    if cal.start_s is not None:
        start = first_epoch(t, cal.start_s)
    else:
        hits = np.flatnonzero(iso == gyro)
        start = int(hits[0]) if hits.size else 0
    if start >= t.size:
        return None
    return Target(gyro, start, _triad(cfg, unit), reason)


def fault_target(cfg: GyrosConfig, unit: GyroUnit, t: np.ndarray) -> Target:
    """The calibration a simulation study runs without the FDI deciding: the configured gyro
    and start, else the first fault's gyro from its time on, else the onset's gyro
    (``scenario.onset``) from the start of the run (its onset time is drawn per episode and
    unknown to the filter). ``ValueError`` if there is none."""
    cal = cfg.calibration
    faults = cfg.scenario.faults
    specs = cfg.scenario.onset_specs()  # an onset mixture's are all on one gyro
    onset = specs[0] if specs else None
    if cal.gyro is None and not faults and onset is None:
        raise ValueError(
            "no gyro to calibrate: the scenario has no fault and calibration.gyro is not set"
        )
    if cal.gyro is not None:
        gyro = unit.index(cal.gyro)
    elif faults:
        gyro = unit.index(faults[0].gyro)
    else:
        assert onset is not None
        gyro = unit.index(onset.gyro)
    start_s = cal.start_s if cal.start_s is not None else (faults[0].t_s if faults else 0.0)
    start = min(first_epoch(t, start_s), t.size - 2)
    return Target(gyro, start, _triad(cfg, unit), "scenario")


def setup_for(cfg: GyrosConfig, unit: GyroUnit, target: Target) -> UkfSetup:
    return make_setup(unit, cfg.calibration, target.gyro, target.triad)


@dataclass(frozen=True)
class RunResult:
    cfg: GyrosConfig
    unit: GyroUnit
    detectors: Detectors
    data: GyroData
    fdi: FdiResult
    target: Target | None
    record: CalibrationRecord | None

    @property
    def truth(self) -> np.ndarray | None:
        """True coefficients of the calibrated gyro over the calibrated epochs (K, 4)."""
        coeffs = self.data.trial_coeffs(0)
        if coeffs is None or self.target is None:
            return None
        return np.asarray(coeffs[self.target.start :, self.target.gyro])


def simulate_run(cfg: GyrosConfig, seed: int | None = None) -> GyroData:
    """One trial of the config's scenario (trial 0 of ``seed``, default ``run.seed``)."""
    unit = build_unit(cfg)
    sc = cfg.scenario
    t = epochs(sc.duration_s, sc.dt_s)
    s = cfg.run.seed if seed is None else seed
    if sc.onset_mixture is not None:  # trial 0's component
        return simulate(unit, sc.body_rate, sc.faults, t, s, [0], onsets=[trial_onset(sc, s, 0)])
    return simulate(unit, sc.body_rate, sc.faults, t, s, [0], sc.onset)


def run(cfg: GyrosConfig, data: GyroData | None = None, seed: int | None = None) -> RunResult:
    """FDI and calibration of one trial: recorded ``data`` or a simulation."""
    unit = build_unit(cfg)
    det = Detectors.build(unit, cfg.fdi)
    if data is None:
        data = simulate_run(cfg, seed)
    fdi = run_fdi(det, data.meas)
    target = choose_target(cfg, unit, fdi, data.t)
    record = None
    if target is not None:
        record = calibrate(
            unit,
            setup_for(cfg, unit, target),
            data.t,
            data.meas[0],
            target.start,
            cfg.calibration.kappa,
        )
    return RunResult(cfg, unit, det, data, fdi, target, record)
