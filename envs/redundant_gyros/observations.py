"""Observations of the redundant-gyro environments: a registry of versions
(docs/redundant_gyros.md, "Environment").

Every version is built from the same per-period quantities (:class:`GyroObservationInputs`,
no truth) for a whole batch of episodes at once; an entry names the quantities in the order it
uses them. ``uses_nominal`` says whether it reads the likelihood gain over a κ = 1 copy of the
filter, which then runs beside the agent's (the only reason that copy exists).

======  ==================================================  ====  ====  ====  ====  ====
name    entry                                                v0    v1    v2    v3    v4
======  ==================================================  ====  ====  ====  ====  ====
sd      ``log10(σ/σ₀)`` of b, λ, δ_u, δ_v (4 entries)        0–3   0–3   0–3   0–3   0–3
nis     mean NIS ``ν²/S`` over the period                    4     4     4     4     4
lag1    mean lag-1 product of ``ν/√S`` over the period       –     –     –     5     5
rscale  ``log10 θ̂_R``, the measurement-noise scale so far    –     –     –     –     6
gain    log-likelihood gain over a κ = 1 copy, per step      5     5     –     –     –
time    elapsed fraction of the episode                      6     –     –     –     –
rate    ``|ω̂_H|`` of the healthy triad at the period's end    7     6     5     6     7
kappa   κ position in [0, 1] on the action scale             8     7     6     7     8
======  ==================================================  ====  ====  ====  ====  ====

``lag1`` separates the two noise levels the NIS confounds: a white noise above the assumed
raises the NIS but leaves the normalised innovations white (``lag1`` ≈ 0); coefficients that
move faster than the filter's process noise make them correlated (``lag1`` > 0).

``rscale`` is what the ``vb-noise`` baseline reads (:mod:`qkf.redundant_gyros.vb_noise`): the
variational-Bayes estimate of the white noise's scale over the assumed, ``θ̂_R = β/α`` of its
inverse-Gamma posterior from the episode's start (no forgetting, a prior worth one period at
1), from the post-fit residuals of every epoch so far. It identifies the white-noise level of
``gyro_noise_levels`` within a few per cent over an episode; a policy that reads it can do
what ``vb-noise`` does, and more if its other entries help (``uses_noise_scale``: the UKF then
keeps each epoch's covariance).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from envs.common.bounds import finite_clipped
from qkf.core.registry import Registry


@dataclass(frozen=True)
class GyroObservationInputs:
    """What an observation may read after a period, per episode (N rows)."""

    p: np.ndarray  # (N, 4, 4) the UKF's covariance at the period's end
    prior_sd: np.ndarray  # (4,) σ₀
    nis: np.ndarray  # (N,) mean ν²/S over the period
    lag1: np.ndarray  # (N,) mean of r_i r_{i−1}, r = ν/√S, over the period
    loglik_gain_per_step: np.ndarray  # (N,) (ℓ − ℓ_nominal) / steps (NaN without the copy)
    elapsed: np.ndarray  # (N,) elapsed fraction of the episode
    rate_norm: np.ndarray  # (N,) |ω̂_H| at the period's last epoch, deg/s
    position: np.ndarray  # (N,) κ position on the action scale
    noise_scale: np.ndarray  # (N,) θ̂_R so far (NaN where the version does not read it)


def _sd(o: GyroObservationInputs) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):  # a failed filter: NaN, cleared after
        return np.log10(np.sqrt(np.diagonal(o.p, axis1=1, axis2=2)) / o.prior_sd)


PARTS: dict[str, Callable[[GyroObservationInputs], np.ndarray]] = {
    "sd": _sd,
    "nis": lambda o: o.nis[:, None],
    "lag1": lambda o: o.lag1[:, None],
    "gain": lambda o: o.loglik_gain_per_step[:, None],
    "time": lambda o: o.elapsed[:, None],
    "rate": lambda o: o.rate_norm[:, None],
    "kappa": lambda o: o.position[:, None],
    "rscale": lambda o: np.log10(o.noise_scale)[:, None],
}
"""The quantities an observation is made of, each (N, entries)."""
PART_SIZES = {
    "sd": 4, "nis": 1, "lag1": 1, "gain": 1, "time": 1, "rate": 1, "kappa": 1, "rscale": 1,
}  # fmt: skip


@dataclass(frozen=True)
class GyroObservation:
    """One observation version: its parts, in order (the κ position is always last)."""

    parts: tuple[str, ...]
    description: str

    @property
    def size(self) -> int:
        return sum(PART_SIZES[p] for p in self.parts)

    @property
    def uses_nominal(self) -> bool:
        """Whether it reads the κ = 1 copy's likelihood."""
        return "gain" in self.parts

    @property
    def uses_noise_scale(self) -> bool:
        """Whether it reads the VB estimate of the white noise's scale ``θ̂_R``."""
        return "rscale" in self.parts

    def build(self, o: GyroObservationInputs) -> np.ndarray:
        """The observations (N, size), float32, finite and clipped."""
        return finite_clipped(np.concatenate([PARTS[p](o) for p in self.parts], axis=1))


GYRO_OBSERVATIONS: Registry[GyroObservation] = Registry("gyro observation")
"""Observation versions of the redundant-gyro environments by name."""
GYRO_OBSERVATIONS.register(
    "v0",
    GyroObservation(("sd", "nis", "gain", "time", "rate", "kappa"), "with the elapsed fraction"),
)
GYRO_OBSERVATIONS.register(
    "v1", GyroObservation(("sd", "nis", "gain", "rate", "kappa"), "v0 without the clock")
)
GYRO_OBSERVATIONS.register(
    "v2",
    GyroObservation(("sd", "nis", "rate", "kappa"), "v1 without the κ = 1 copy's likelihood gain"),
)
GYRO_OBSERVATIONS.register(
    "v3",
    GyroObservation(
        ("sd", "nis", "lag1", "rate", "kappa"), "v2 with the innovations' lag-1 correlation"
    ),
)
GYRO_OBSERVATIONS.register(
    "v4",
    GyroObservation(
        ("sd", "nis", "lag1", "rscale", "rate", "kappa"),
        "v3 with the VB estimate of the white noise's scale",
    ),
)
