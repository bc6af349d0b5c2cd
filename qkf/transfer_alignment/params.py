"""The transfer-alignment problem's constants in SI, derived once from a config.

:class:`TruthParams` is what the simulator uses (the world as it is), :class:`FilterParams`
what the filter assumes; they differ in noise-mismatch studies. :func:`prior_sigma` is the
prior of the error state, shared by both: the filter starts from ``P_0 = diag(prior²)``,
``randomize_truth`` draws the truth from it, and the CRLB starts from ``J_0 = P_0⁻¹``.
See docs/models.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from qkf.core import units
from qkf.transfer_alignment.config import Config, Scenario


def prior_sigma(cfg: Config) -> np.ndarray:
    """Prior 1-σ of the 15 error states (SI): attitude, bias, calibration."""
    init = cfg.filter.initial_sigma
    return np.array(
        [init.attitude_arcsec * units.ARCSEC] * 3
        + [init.bias_degph * units.DEG_PER_H] * 3
        + [init.calibration_ppm * units.PPM] * 9
    )


def n_epochs(sc: Scenario) -> int:
    """Number of epochs ``N = round(duration / Δt)``."""
    return round(sc.duration_s / sc.dt_s)


@dataclass(frozen=True)
class TruthParams:
    """Scenario constants in SI."""

    dt: float
    n_epochs: int
    sigma_v: float  # rad/√s
    sigma_u: float  # rad/s^1.5
    sigma_a: float  # rad (true ADS attitude noise)
    sigma_r: float  # rad/s (true ADS rate noise)
    b0: np.ndarray  # (3,) rad/s
    p0: np.ndarray  # (9,)
    randomize_truth: bool
    prior_sigma_b: float  # rad/s, used when randomize_truth
    prior_sigma_p: float  # used when randomize_truth

    @classmethod
    def from_config(cls, cfg: Config) -> TruthParams:
        sc = cfg.scenario
        tr = sc.truth
        prior = prior_sigma(cfg)
        return cls(
            dt=sc.dt_s,
            n_epochs=n_epochs(sc),
            sigma_v=sc.gyro.arw_deg_sqrt_h * units.DEG_PER_SQRT_H,
            sigma_u=sc.gyro.rrw_deg_h_1_5 * units.DEG_PER_H_1_5,
            sigma_a=sc.ads.attitude_sigma_arcsec * units.ARCSEC,
            sigma_r=sc.ads.rate_sigma_degph * units.DEG_PER_H,
            b0=np.asarray(tr.bias_degph) * units.DEG_PER_H,
            p0=np.concatenate(
                [
                    np.asarray(tr.scale_factor_ppm) * units.PPM,
                    np.asarray(tr.misalignment_urad) * units.URAD,
                ]
            ),
            randomize_truth=sc.randomize_truth,
            prior_sigma_b=float(prior[3]),
            prior_sigma_p=float(prior[6]),
        )


@dataclass(frozen=True)
class FilterParams:
    """What the filter assumes, in SI."""

    dt: float
    sigma_v: float  # rad/√s
    sigma_u: float  # rad/s^1.5
    sigma_a: float  # rad
    sigma_r: float  # rad/s
    qp0: float  # 1/s
    use_rate: bool
    p0_sigma: np.ndarray = field(repr=False)  # (15,) prior sigmas, SI
    quadrature_nodes: int = 5
    rate_noise_correlation: bool = True

    @classmethod
    def from_config(cls, cfg: Config) -> FilterParams:
        sc, fc = cfg.scenario, cfg.filter
        return cls(
            dt=sc.dt_s,
            sigma_v=(fc.arw_deg_sqrt_h or sc.gyro.arw_deg_sqrt_h) * units.DEG_PER_SQRT_H,
            sigma_u=(fc.rrw_deg_h_1_5 or sc.gyro.rrw_deg_h_1_5) * units.DEG_PER_H_1_5,
            sigma_a=(fc.attitude_sigma_arcsec or sc.ads.attitude_sigma_arcsec) * units.ARCSEC,
            sigma_r=(fc.rate_sigma_degph or sc.ads.rate_sigma_degph) * units.DEG_PER_H,
            qp0=fc.qp0,
            use_rate=fc.matching == "attitude_rate",
            p0_sigma=prior_sigma(cfg),
            quadrature_nodes=fc.quadrature_nodes,
            rate_noise_correlation=fc.rate_noise_correlation,
        )

    @property
    def n_meas(self) -> int:
        return 6 if self.use_rate else 3
