"""Fusion of one arc: Gauss–Newton with variance components and Huber weights on the core
(:func:`qkf.core.least_squares.iterate`), then the covariance from the last factor
(docs/sca_fusion.md, "Solution and covariance")."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from qkf.core.least_squares import IterationInfo, IterationSettings, Linearization, iterate
from qkf.core.vce import RobustSettings
from qkf.sca_fusion.config import Estimator, FusionConfig
from qkf.sca_fusion.data import ArcData, Arcs, Series, split_arcs
from qkf.sca_fusion.design import (
    AXES,
    CalibrationLayout,
    apply_step,
    arc_model,
    calibration_effect,
    linearize,
)
from qkf.sca_fusion.scenario import SimulatedData, simulate


@dataclass(frozen=True)
class ArcSolution:
    """The fused arc. Sigmas are those of the last solve (``N⁻¹`` with the estimated weights)."""

    t: np.ndarray
    q: np.ndarray  # (n, 4) fused, sign-continuous
    sigma: np.ndarray  # (n, 3) rad, per body axis
    layout: CalibrationLayout
    calibration: np.ndarray  # (g,) bias rad/s², scale dimensionless
    calibration_sd: np.ndarray  # (g,)
    calibration_cov: np.ndarray  # (g, g)
    sigma_sca: np.ndarray  # (3,) rad: a-priori × variance factor (equal if one factor)
    sigma_acc: np.ndarray  # (3,) rad/s²
    sca_components: tuple[str, ...]
    acc_components: tuple[str, ...]
    epoch_sigma_sca: np.ndarray  # (n,) Huber factor, NaN where no star camera
    epoch_sigma_acc: np.ndarray  # (n,) NaN where no accelerometer
    acc_calibrated: np.ndarray  # (n, 3) acc − b − s ⊙ acc, NaN where no accelerometer
    sca_residual: np.ndarray  # (n, 3) rad, star camera − fused (last linearisation), NaN
    sigma0: list[float]
    iterations: int
    converged: bool
    has_sca: np.ndarray
    has_acc: np.ndarray


def iteration_settings(est: Estimator) -> IterationSettings:
    return IterationSettings(
        max_iterations=est.iteration_count,
        tolerance=est.convergence_sigma0,
        variance_components=est.variance_component_estimation,
        robust=RobustSettings(huber=est.huber, power=est.huber_power),
    )


def _per_axis(f: np.ndarray, prior: np.ndarray) -> np.ndarray:
    return prior * (f if f.size == 3 else np.repeat(f, 3))


def fuse_arc(
    arc: ArcData,
    est: Estimator,
    taylor: np.ndarray | None = None,
    on_iteration: Callable[[IterationInfo], None] | None = None,
) -> ArcSolution:
    """Fuse one arc; ``taylor`` (n, 4) overrides the Taylor point (default: the star camera,
    slerped over epochs without one)."""
    model = arc_model(arc, est)
    n = arc.n
    state = {
        "q": (arc.taylor_point() if taylor is None else np.asarray(taylor, float)).copy(),
        "cal": np.zeros(model.layout.size),
    }

    def lin() -> Linearization:
        return linearize(model, state["q"], state["cal"])

    def update(dx: np.ndarray) -> None:
        state["q"] = apply_step(state["q"], dx, n)
        state["cal"] = state["cal"] + dx[3 * n :]

    res = iterate(lin, update, iteration_settings(est), on_iteration)
    factor = res.factor
    diag = factor.inverse_band()[0]
    sigma = np.sqrt(np.stack([diag[:n], diag[n : 2 * n], diag[2 * n :]], axis=1))
    cov = factor.border_covariance()
    epoch_sca = np.full(n, np.nan)
    epoch_acc = np.full(n, np.nan)
    fe = res.epoch_sigma.get("sca", np.ones(0))
    epoch_sca[arc.has_sca] = fe[np.flatnonzero(arc.has_sca)]
    if "acc" in res.epoch_sigma:
        fa = res.epoch_sigma["acc"]
        epoch_acc[arc.has_acc] = fa[np.flatnonzero(arc.has_acc)]
    sca_res = np.full((n, 3), np.nan)
    sca_res[arc.has_sca] = res.residual["sca"].reshape(-1, 3)
    acc_cal = arc.acc - calibration_effect(model, state["cal"])
    sca_prior = np.full(3, est.sigma_star_camera_rad)
    acc_prior = np.asarray(est.sigma_accelerometer_rad_s2, dtype=float)
    f_acc = res.component_sigma.get("acc", np.ones(3))
    return ArcSolution(
        t=arc.t,
        q=state["q"],
        sigma=sigma,
        layout=model.layout,
        calibration=state["cal"],
        calibration_sd=np.sqrt(np.diag(cov)),
        calibration_cov=cov,
        sigma_sca=_per_axis(res.component_sigma["sca"], sca_prior),
        sigma_acc=_per_axis(f_acc, acc_prior),
        sca_components=AXES if est.estimate_sigma_sca_per_axis else ("all",),
        acc_components=AXES if est.estimate_sigma_acc_per_axis else ("all",),
        epoch_sigma_sca=epoch_sca,
        epoch_sigma_acc=epoch_acc,
        acc_calibrated=acc_cal,
        sca_residual=sca_res,
        sigma0=res.sigma0,
        iterations=res.iterations,
        converged=res.converged,
        has_sca=arc.has_sca,
        has_acc=arc.has_acc,
    )


@dataclass(frozen=True)
class FusionRun:
    """A whole run: the arcs, their solutions, what was skipped, and the simulation (with its
    truth) when no data files were given."""

    source: str
    arcs: list[ArcData]
    solutions: list[ArcSolution]
    skipped: list[str]
    simulation: SimulatedData | None
    runtime_s: float


def arcs_from_series(sca: Series, acc: Series, cfg: FusionConfig) -> Arcs:
    """Merge two input series into arcs with the config's tolerances."""
    return split_arcs(
        sca.t,
        sca.values,
        acc.t,
        acc.values,
        cfg.data.time_match_tolerance_s,
        cfg.arcs.spacing_tolerance,
        max(cfg.arcs.min_epochs, cfg.estimator.interpolation_degree + 1),
    )


def run_fusion(
    cfg: FusionConfig,
    data: tuple[Series, Series] | None = None,
    on_arc: Callable[[int, int], None] | None = None,
    on_iteration: Callable[[IterationInfo], None] | None = None,
) -> FusionRun:
    """Fuse the given (SCA, ACC) series, or simulate them from ``cfg.simulation``, arc by arc.
    ``on_arc(k, count)`` is called before arc k (0-based) is solved."""
    t0 = time.perf_counter()
    sim = None
    if data is None:
        sim = simulate(cfg.simulation)
        sca = Series("<simulation>", sim.sca_t, sim.sca_q)
        acc = Series("<simulation>", sim.acc_t, sim.acc)
        source = f"simulation (seed {cfg.simulation.seed})"
    else:
        sca, acc = data
        source = f"{sca.path} + {acc.path}"
    arcs = arcs_from_series(sca, acc, cfg)
    solutions = []
    for k, arc in enumerate(arcs.arcs):
        if on_arc is not None:
            on_arc(k, len(arcs.arcs))
        solutions.append(fuse_arc(arc, cfg.estimator, on_iteration=on_iteration))
    return FusionRun(source, arcs.arcs, solutions, arcs.skipped, sim, time.perf_counter() - t0)
