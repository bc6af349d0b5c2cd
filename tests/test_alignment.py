"""Attitude-independent alignment calibration (docs/alignment.md): the model against finite
differences and Monte Carlo, recovery of 1° misalignments, NEES over trials, and the report of
directions the data cannot see."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from qkf.alignment.config import load_config
from qkf.alignment.data import Observations
from qkf.alignment.model import form_pairs, jacobian, pair_covariance, residuals, rotated
from qkf.alignment.scenario import simulate
from qkf.alignment.solve import solve
from qkf.core import units

PRESET = "alignment_three_sensors"
FROM_PRIOR = ("sensors.1.misalignment_deg=null", "sensors.2.misalignment_deg=null")


def _nees(sol, truth) -> float:  # type: ignore[no-untyped-def]
    e = (sol.theta - truth)[sol.free].ravel()
    return float(e @ np.linalg.solve(sol.cov, e))


def test_jacobian_matches_finite_differences() -> None:
    cfg = load_config(PRESET, ["simulation.epochs=30"])
    obs, _ = simulate(cfg, 0)
    pairs = form_pairs(obs, 1e-6)
    rng = np.random.default_rng(3)
    theta = rng.uniform(-1.0, 1.0, (3, 3)) * units.DEG  # every sensor, the reference too
    free = [1, 2]
    u = rotated(theta, obs)
    jac = jacobian(theta, u, obs, pairs, free)
    h = 1e-7
    fd = np.empty_like(jac)
    for c in range(6):
        dt = np.zeros_like(theta)
        dt[free[c // 3], c % 3] = h
        zp = residuals(rotated(theta - dt, obs), obs, pairs)  # z = r·r − u·u: ∂z/∂θ = −∂(u·u)/∂θ
        zm = residuals(rotated(theta + dt, obs), obs, pairs)
        fd[:, c] = (zp - zm) / (2 * h)
    # the sign convention: z ≈ H dθ means ∂(u_a·u_b)/∂θ = H
    np.testing.assert_allclose(jac, fd, atol=1e-8 * np.abs(jac).max())
    assert np.abs(jac).max() > 0.5


def _one_epoch(u: np.ndarray, sensor: np.ndarray, sigma_rad: np.ndarray) -> Observations:
    n = len(sensor)
    return Observations(
        names=tuple(f"s{i}" for i in range(len(sigma_rad))),
        t=np.zeros(n),
        sensor=np.asarray(sensor),
        w=u,
        r=u,
        row=np.arange(1, n + 1),
    )


@pytest.mark.parametrize("sensor", [[0, 1, 2], [0, 0, 1, 1, 2]])
def test_pair_covariance_matches_monte_carlo(sensor: list[int]) -> None:
    """The first-order pair covariance, including the correlation of pairs that share an
    observation, against noisy vectors drawn as the simulator draws them; and its rank,
    2m − 3 at most for m vectors (a common rotation of all of them changes no angle)."""
    rng = np.random.default_rng(7)
    u = rng.normal(size=(len(sensor), 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    sigma = np.array([5.0, 20.0, 60.0]) * units.ARCSEC
    obs = _one_epoch(u, np.array(sensor), sigma)
    pairs = form_pairs(obs, 0.0)
    cov = pair_covariance(u, sigma, obs, pairs)[0]
    first = pair_covariance(u, sigma, obs, pairs, second_order=False)[0]
    draws = 40_000
    noise = rng.normal(size=(draws, *u.shape)) * sigma[obs.sensor][None, :, None]
    w = u[None] + noise
    w /= np.linalg.norm(w, axis=2, keepdims=True)
    z = np.einsum("dpi,dpi->dp", w[:, pairs.a], w[:, pairs.b])
    emp = np.cov(z, rowvar=False)
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(np.sqrt(np.diag(emp)) / sd, 1.0, atol=0.03)
    np.testing.assert_allclose(emp / np.outer(sd, sd), cov / np.outer(sd, sd), atol=0.03)
    eig = np.linalg.eigvalsh(first)
    assert np.sum(eig > 1e-10 * eig[-1]) == min(pairs.n, 2 * len(sensor) - 3)
    # the first-order diagonal is the textbook (σ_a² + σ_b²)|u_a × u_b|²
    n2 = np.sum(np.cross(u[pairs.a], u[pairs.b]) ** 2, axis=1)
    s2 = sigma[obs.sensor] ** 2
    np.testing.assert_allclose(np.diag(first), (s2[pairs.a] + s2[pairs.b]) * n2, rtol=1e-12)
    # the second-order terms: off the diagonal nothing, on it below 1e-6 here
    np.testing.assert_array_equal(cov - np.diag(np.diag(cov)), first - np.diag(np.diag(first)))
    ratio = np.diag(cov) / np.diag(first)
    assert np.all(ratio > 1.0) and np.all(ratio < 1.000001)


def test_nearly_parallel_pair_keeps_a_finite_weight() -> None:
    """Two sensors seeing the same direction (|u_a × u_b| = 0): to first order the pair's
    variance vanishes; the second-order terms give the variance of z (its mean, 2σ² from the
    normalisation of the vectors, is not modelled: it is 3e-4 σ of a pair at 90° for 60″)."""
    rng = np.random.default_rng(2)
    sigma = np.array([5.0, 5.0]) * units.ARCSEC
    u = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    obs = _one_epoch(u, np.array([0, 1]), sigma)
    pairs = form_pairs(obs, 0.0)
    var = pair_covariance(u, sigma, obs, pairs)[0, 0, 0]
    noisy = u + rng.normal(size=(20_000, 2, 3)) * sigma[0]
    noisy /= np.linalg.norm(noisy, axis=2, keepdims=True)
    z = 1.0 - np.einsum("di,di->d", noisy[:, 0], noisy[:, 1])
    assert pair_covariance(u, sigma, obs, pairs, second_order=False)[0, 0, 0] == 0.0
    assert 0.9 < np.var(z) / var < 1.1
    assert np.mean(z) == pytest.approx(2 * sigma[0] ** 2, rel=0.05)


def test_misalignments_up_to_one_degree_recovered_within_three_sigma() -> None:
    """True alignments of the preset reach 1° per axis. Gauss–Newton brings every component
    to noise level (within 3 σ, over ten independent runs), where one linearised step about
    zero leaves errors of tens of σ (the prior cannot be what makes them small: it is 0.5°)."""
    cfg = load_config(PRESET)
    truth_deg = np.abs([s.misalignment_deg or (0, 0, 0) for s in cfg.sensors])
    assert truth_deg.max() == pytest.approx(1.0)
    normalised, first_step = [], []
    for trial in range(10):
        obs, truth = simulate(cfg, trial)
        sol = solve(cfg, obs)
        assert sol.converged and sol.iterations <= 6
        assert np.all(sol.theta[0] == 0.0) and np.all(sol.sd[0] == 0.0)
        normalised.append(((sol.theta - truth) / np.where(sol.sd > 0, sol.sd, 1.0))[1:])
        first_step.append(((sol.history[1] - truth) / np.where(sol.sd > 0, sol.sd, 1.0))[1:])
    z = np.concatenate(normalised).ravel()  # 60 components
    # within 3 σ: at most one of the 60 outside (1.4 % chance for consistent Gaussian errors)
    assert np.sum(np.abs(z) > 3.0) <= 1 and np.all(np.abs(z) < 4.5), np.round(z, 2)
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.4
    assert np.max(np.abs(np.concatenate(first_step))) > 10.0


def _nees_over_trials(overrides: tuple[str, ...], trials: int) -> np.ndarray:
    cfg = load_config(PRESET, [*FROM_PRIOR, "simulation.epochs=100", *overrides])
    out = []
    for trial in range(trials):
        obs, truth = simulate(cfg, trial, seed=11)
        out.append(_nees(solve(cfg, obs), truth))
    return np.array(out)


@pytest.mark.slow
def test_nees_inside_chi_square_band_and_pair_correlation_matters() -> None:
    """Truth drawn from the prior: the average NEES of the 6 unknowns over 100 trials lies in
    the 99 % band of χ²₆₀₀/100. Weighting each pair by its own variance only (ignoring that
    the pairs of an epoch share observations) makes the covariance over-confident."""
    trials = 100
    avg = _nees_over_trials((), trials).mean()
    lo, hi = stats.chi2.ppf([0.005, 0.995], 6 * trials) / trials
    assert lo < avg < hi, (avg, lo, hi)
    diag = _nees_over_trials(("solver.correlated_pairs=false",), 40).mean()
    assert diag > stats.chi2.ppf(0.995, 6 * 40) / 40, diag


def _two_sensor_config(extra: tuple[str, ...] = ()):  # type: ignore[no-untyped-def]
    """The reference always sees the same body direction (+z, e.g. a sun sensor with the sun
    held on its boresight), so the other sensor's rotation about +z changes no angle."""
    return load_config(
        PRESET,
        [
            "sensors=[{name: ref, sigma_arcsec: 5, boresight: [0, 0, 1], fov_deg: 0},"
            " {name: st, sigma_arcsec: 5, boresight: [1, 0, 0], fov_deg: 10, per_epoch: 2,"
            "  misalignment_deg: [0.2, -0.3, 0.4]}]",
            "reference=ref",
            *extra,
        ],
    )


def test_unobservable_direction_is_reported_not_filled_by_the_prior() -> None:
    cfg = _two_sensor_config()
    obs, truth = simulate(cfg, 0)
    sol = solve(cfg, obs)
    assert sol.rank == 2 and sol.n_unknowns == 3
    weak = sol.unobservable()
    assert len(weak) == 1
    d = weak[0]
    assert d.rank_deficient and d.prior_determined
    ((name, axis, share),) = d.axes
    assert name == "st" and share == pytest.approx(1.0)
    assert abs(axis @ np.array([0.0, 0.0, 1.0])) > 0.999
    assert d.relative < 1e-6
    # the posterior along it is the prior: sd unchanged, the estimate near the prior mean (0)
    # rather than the truth's 0.4°, and the reported σ covers the error
    assert d.sd == pytest.approx(d.prior_sd, rel=0.01)
    assert abs(sol.theta[1, 2]) < 0.2 * d.prior_sd < 0.5 * abs(truth[1, 2])
    assert abs(sol.theta[1, 2] - truth[1, 2]) < 3.0 * sol.sd[1, 2]
    assert sol.prior_share[1, 2] > 0.98 and np.all(sol.prior_share[1, :2] < 1e-4)
    # the observable components are recovered to noise level
    z = (sol.theta[1, :2] - truth[1, :2]) / sol.sd[1, :2]
    assert np.all(np.abs(z) < 3.0)
    # the observable directions are not flagged
    strong = [di for di in sol.directions if not di.unobservable]
    assert len(strong) == 2 and all(di.relative > 1e-2 for di in strong)


def test_reference_observing_one_direction_only_on_some_epochs_is_observable() -> None:
    """The same pair of sensors with the reference's field of view opened to 10°: the rotation
    about +z is seen (the flag is not raised just because a direction is weak)."""
    cfg = _two_sensor_config(("sensors.0.fov_deg=10",))
    obs, _ = simulate(cfg, 0)
    sol = solve(cfg, obs)
    assert sol.rank == 3 and not sol.unobservable()
