"""The calibration UKF: its measurement model against the truth simulation, the parity (left
null space) identity, R against a Monte Carlo, a hand-computed estimate when the problem is
linear, and on the paper's two scenarios convergence and NEES inside the χ² band over trials."""

from __future__ import annotations

import numpy as np
import pytest

from qkf.core.stats import nees
from qkf.core.units import DEG
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.config import GyrosConfig
from qkf.redundant_gyros.geometry import GyroUnit, build_unit, parity_matrix
from qkf.redundant_gyros.metrics import convergence_step, convergence_tolerance, nees_band
from qkf.redundant_gyros.pipeline import Target, fault_target, setup_for
from qkf.redundant_gyros.scenario import epochs, simulate
from qkf.redundant_gyros.ukf import (
    UkfSetup,
    axis_gain,
    calibrate,
    make_setup,
    measurement,
    measurement_variance,
    triad_rate,
)


def _unit_setup(
    preset: str = "five_gyros_s_bias", sets: list[str] | None = None
) -> tuple[GyrosConfig, GyroUnit, np.ndarray, Target, UkfSetup]:
    cfg = load_config(preset, sets or [])
    unit = build_unit(cfg)
    t = epochs(cfg.scenario.duration_s, cfg.scenario.dt_s)
    target = fault_target(cfg, unit, t)
    return cfg, unit, t, target, setup_for(cfg, unit, target)


def test_measurement_model_equals_the_simulated_reading() -> None:
    """h(x, ω) with the true rate reproduces the scenario's noise-free reading of the gyro."""
    _, unit, _, _, setup = _unit_setup()
    rng = np.random.default_rng(1)
    for _ in range(50):
        x = np.array([rng.normal(0, 0.1), rng.normal(0, 0.01), *rng.normal(0, 0.3, 2)])
        rate = rng.normal(0, 5, 3)
        coeffs = unit.nominal.copy()
        coeffs[setup.gyro] = x
        expected = unit.readings(coeffs, rate)[setup.gyro]
        assert measurement(x, rate, setup)[0] == pytest.approx(expected, rel=1e-12, abs=1e-15)


def test_the_measurement_is_the_left_null_space_combination() -> None:
    """n = [−G_H⁻ᵀ a; 1] annihilates [G_H; aᵀ] and is parallel to the parity vector of those
    four gyros computed by QR."""
    _, unit, _, _, setup = _unit_setup()
    x = np.array([0.1, 0.004, 0.2, -0.1])
    g = np.vstack([unit.g[list(setup.triad)], axis_gain(setup, x)])
    n = np.append(-setup.triad_inv.T @ axis_gain(setup, x), 1.0)
    assert np.abs(n @ g).max() < 1e-13
    v = parity_matrix(g)[0]
    assert abs(abs(v @ n) / np.linalg.norm(n) - 1.0) < 1e-12


def test_measurement_variance_against_monte_carlo() -> None:
    _, unit, _, _, setup = _unit_setup()
    x = np.array([0.1, 0.003, 0.05, -0.02])
    rng = np.random.default_rng(2)
    rate = np.array([1.0, -2.0, 0.5])
    coeffs = np.broadcast_to(unit.nominal, (200_000, unit.n, 4)).copy()
    coeffs[:, setup.gyro] = x
    clean = unit.readings(coeffs, np.broadcast_to(rate, (200_000, 3)))
    meas = clean - unit.noise * rng.standard_normal(clean.shape)
    rates = triad_rate(unit, setup, meas)
    h = np.array([measurement(x, r, setup)[0] for r in rates[:100]])
    np.testing.assert_allclose(h, rates[:100] @ axis_gain(setup, x) - x[0], rtol=1e-12)
    resid = meas[:, setup.gyro] - (rates @ axis_gain(setup, x) - x[0])
    r = measurement_variance(setup, x)
    assert abs(resid.mean()) < 4 * np.sqrt(r / resid.size)
    assert resid.var() == pytest.approx(r, rel=4 * np.sqrt(2 / resid.size))


def test_bias_only_matches_the_hand_computed_weighted_mean() -> None:
    """With λ and δ pinned by a tiny prior and no process noise, the measurement is linear in b:
    m = a·ω̂ − b + ν, so b̂ = (b₀/σ₀² + Σ (a·ω̂ − m)/R) / (1/σ₀² + Σ 1/R)."""
    sets = [
        "calibration.initial_sigma.scale=1e-12",
        "calibration.initial_sigma.delta_deg=1e-10",
        "calibration.process_noise.bias_deg_s_per_sqrt_s=0",
        "calibration.process_noise.scale_per_sqrt_s=0",
        "calibration.process_noise.delta_deg_per_sqrt_s=0",
        "scenario.duration_s=80",
    ]
    cfg, unit, t, target, setup = _unit_setup(sets=sets)
    data = simulate(unit, cfg.scenario.body_rate, cfg.scenario.faults, t, 4, [0])
    rec = calibrate(unit, setup, t, data.meas[0], target.start)
    a = axis_gain(setup, setup.x0)
    pred = triad_rate(unit, setup, data.meas[0, target.start :]) @ a
    z = data.meas[0, target.start :, setup.gyro]
    r = measurement_variance(setup, setup.x0)
    s0 = setup.p0_sd[0] ** 2
    info = 1 / s0 + np.arange(1, z.size + 1) / r
    b_hat = (setup.x0[0] / s0 + np.cumsum(pred - z) / r) / info
    np.testing.assert_allclose(rec.x[:, 0], b_hat, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(rec.sd[:, 0], np.sqrt(1 / info), rtol=1e-6)
    np.testing.assert_allclose(rec.x[-1, 0], 0.1, atol=5 * rec.sd[-1, 0])


def test_the_triad_excludes_the_gyro_and_is_the_best_conditioned() -> None:
    _, unit, _, _, setup = _unit_setup()
    assert unit.ids[setup.gyro] == "S"
    assert setup.gyro not in setup.triad
    dets = {
        tri: abs(np.linalg.det(unit.g[list(tri)]))
        for tri in [(0, 1, 2), (0, 1, 4), (0, 2, 4), (1, 2, 4)]
    }
    assert setup.triad == max(dets, key=lambda k: dets[k])
    cfg = load_config("five_gyros_s_bias")
    with pytest.raises(ValueError, match="must not contain"):
        make_setup(unit, cfg.calibration, setup.gyro, (setup.gyro, 0, 1))


TRIALS = 20
STEPS = 600


@pytest.mark.parametrize("preset", ["five_gyros_y_misalignment", "five_gyros_s_bias"])
def test_paper_scenarios_converge_and_are_consistent(preset: str) -> None:
    """Over Monte Carlo trials from the fault on: every trial converges within 400 steps (the
    paper: about 400), and the mean NEES is inside the 99 % χ²(4M)/M band at checkpoints and on
    average over the run."""
    cfg, unit, t, target, setup = _unit_setup(preset, ["scenario.duration_s=120"])
    assert target.start == 600 and t.size - target.start == STEPS
    data = simulate(unit, cfg.scenario.body_rate, cfg.scenario.faults, t, 8, range(TRIALS))
    assert data.coeffs is not None
    truth = data.coeffs[target.start :, setup.gyro]
    tol = convergence_tolerance(cfg)
    ne = np.empty((TRIALS, STEPS))
    for m in range(TRIALS):
        rec = calibrate(unit, setup, t, data.meas[m], target.start)
        assert not rec.diverged
        err = rec.x - truth
        step = convergence_step(err, tol)
        assert step is not None and step <= 400, (m, step)
        ne[m] = nees(err, rec.cov)
    lo, hi = nees_band(4, TRIALS, 0.99)
    for k in (50, 100, 200, 400, STEPS - 1):
        assert lo <= ne[:, k].mean() <= hi, (k, ne[:, k].mean(), (lo, hi))
    # averaging correlated checkpoints only narrows the spread: the same band holds
    assert lo <= ne[:, 100:].mean() <= hi
    # the paper's injected values are what was recovered
    paper = {"five_gyros_y_misalignment": (2, -10.0), "five_gyros_s_bias": (0, 0.1)}[preset]
    scale = np.array([1.0, 1.0, DEG, DEG])
    assert truth[-1, paper[0]] / scale[paper[0]] == pytest.approx(paper[1])
    assert abs(rec.x[-1, paper[0]] - truth[-1, paper[0]]) < tol[paper[0]]
