"""The batch least-squares method (``batch``, docs/methods.md): sensitivities against finite
differences, one Gauss–Newton pass and the smoother against a dense generalised least-squares
computation on a short run, and efficiency (RMS at the CRLB) and consistency (NEES) over Monte
Carlo trials."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from qkf.core.so3 import exp_matrix, left_jacobian
from qkf.core.stats import nees
from qkf.transfer_alignment.crlb import crlb
from qkf.transfer_alignment.methods import METHODS, validate_output
from qkf.transfer_alignment.methods.batch import (
    propagate_sensitivity,
    run_batch,
    solve_batch,
)
from qkf.transfer_alignment.methods.covariance import covariance_epochs
from qkf.transfer_alignment.methods.fixed import run_kf
from qkf.transfer_alignment.metrics import state_errors
from qkf.transfer_alignment.model import omega_matrix
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with

SHORT = (
    "scenario.duration_s=40",
    "scenario.maneuvers=[{start_s: 2, duration_s: 10, axis: x, rate_deg_s: 1.0},"
    " {start_s: 12, duration_s: 10, axis: y, rate_deg_s: -2.0},"
    " {start_s: 22, duration_s: 10, axis: z, rate_deg_s: 1.5}]",
    "scenario.ads.gaps=[{start_s: 15, end_s: 19}]",
    "run.nees_every_s=7",
    "scenario.randomize_truth=true",
)


def _log(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    return (Rotation.from_quat(q_from).inv() * Rotation.from_quat(q_to)).as_rotvec()


def test_registered_as_a_builtin_method() -> None:
    assert METHODS["batch"] is run_batch


def test_sensitivity_matches_finite_differences() -> None:
    """``Ĉ_k(y + h eᵢ) ≈ Ĉ_k(y) Exp(S_k h eᵢ)``: the propagated sensitivity, with a non-zero
    α (the J_r(α) factor), bias and calibration, during rotations about every axis."""
    cfg = cfg_with(*SHORT)
    data = simulate(cfg, 5, 1)
    rng = np.random.default_rng(1)
    y = np.concatenate([rng.normal(0, 2e-3, 3), rng.normal(0, 1e-5, 3), rng.normal(0, 2e-3, 9)])
    gyro, q0, dt = data.gyro[0], data.ads_q[0, 0], data.dt
    q, _, sens = propagate_sensitivity(gyro, q0, y, dt)
    steps = np.array([1e-6] * 3 + [1e-9] * 3 + [1e-6] * 9)
    fd = np.empty_like(sens)
    for i in range(15):
        dy = np.zeros(15)
        dy[i] = steps[i]
        q_plus, _, _ = propagate_sensitivity(gyro, q0, y + dy, dt)
        q_minus, _, _ = propagate_sensitivity(gyro, q0, y - dy, dt)
        fd[:, :, i] = (_log(q, q_plus) - _log(q, q_minus)) / (2 * steps[i])
    scale = np.max(np.abs(sens), axis=(0, 1))
    assert np.all(scale > 0)
    np.testing.assert_allclose(sens / scale, fd / scale, atol=2e-6)
    # the bias columns grow with time (s), the x scale factor only once x turns (rad)
    assert np.abs(sens[-1, :, 3:6]).max() > 30.0
    assert np.abs(sens[2, :, 6]).max() < 1e-3 * np.abs(sens[-1, :, 6]).max()
    assert np.abs(sens[-1, :, 6]).max() > 0.1


def _dense_reference(cfg, data, params):  # type: ignore[no-untyped-def]
    """Generalised least squares at y = 0 written out densely: the residuals, their Jacobian
    and the linear map from every white noise sample (gyro, bias walk, ADS attitude and rate)
    to the residual noise, built independently of the kernel."""
    n, dt = data.n_epochs, data.dt
    use_rate = params.use_rate
    y0 = np.zeros(15)
    q, w, sens = propagate_sensitivity(data.gyro[0], data.ads_q[0, 0], y0, dt)
    a = np.eye(3)  # p = 0
    rot = exp_matrix(-w * dt)
    gam = dt * left_jacobian(-w * dt)
    # white noise: η_k (3n), u_k (3n), ν_a,k (3n), ν_r,k (3n)
    n_w = 12 * n
    var = np.concatenate(
        [
            np.full(3 * n, params.sigma_v**2 / dt),
            np.full(3 * n, params.sigma_u**2 * dt),
            np.full(3 * n, params.sigma_a**2),
            np.full(3 * n, params.sigma_r**2),
        ]
    )

    def cols(block: int, k: int) -> slice:
        return slice(3 * (block * n + k), 3 * (block * n + k) + 3)

    nuis = np.zeros((n, 6, n_w))  # [ξ_k, β_k] as a map of the noise
    for k in range(n - 1):
        nuis[k + 1, 0:3] = rot[k] @ nuis[k, 0:3] - gam[k] @ a @ nuis[k, 3:6]
        nuis[k + 1, 0:3, cols(0, k)] -= gam[k] @ a
        nuis[k + 1, 3:6] = nuis[k, 3:6]
        nuis[k + 1, 3:6, cols(1, k)] += np.eye(3)
    z_att = _log(q, data.ads_q[0])
    z_rate = data.ads_rate[0] - w
    rows_r, rows_h, rows_l = [], [], []
    for k in np.flatnonzero(data.has_meas):
        lam = nuis[k, 0:3].copy()
        lam[:, cols(2, k)] += np.eye(3)
        rows_r.append(z_att[k])
        rows_h.append(sens[k])
        rows_l.append(lam)
        if use_rate:
            lam = -a @ nuis[k, 3:6]
            lam[:, cols(0, k)] -= a
            lam[:, cols(3, k)] += np.eye(3)
            h = np.zeros((3, 15))
            h[:, 3:6] = -a
            h[:, 6:15] = -a @ omega_matrix(w[k])
            rows_r.append(z_rate[k])
            rows_h.append(h)
            rows_l.append(lam)
    r = np.concatenate(rows_r)
    h = np.concatenate(rows_h)
    lmap = np.concatenate(rows_l)
    # scale rows to unit order before any solve
    e = np.sqrt(np.einsum("ij,j,ij->i", lmap, var, lmap))
    r, h, lmap = r / e, h / e[:, None], lmap / e[:, None]
    prior = params.p0_sigma**2
    # joint posterior of θ = [Δy, w] given r = H Δy + L w (a Gaussian conditioning)
    jac = np.hstack([h, lmap])
    p_theta = np.concatenate([prior, var])
    cross = jac * p_theta  # J P (P diagonal)
    s = cross @ jac.T
    post_mean = cross.T @ np.linalg.solve(s, r)
    post_cov = np.diag(p_theta) - cross.T @ np.linalg.solve(s, cross)
    # the nuisance given Δy = 0 (what the estimates at the linearisation point report)
    sigma = (lmap * var) @ lmap.T
    nuis_given_y = np.einsum("kiw,w,rw->kir", nuis, var, lmap) @ np.linalg.solve(sigma, r)
    return {
        "step": post_mean[:15],
        "cov_y": post_cov[:15, :15],
        "post_cov": post_cov,
        "nuis": nuis,
        "sens": sens,
        "nuis_given_y": nuis_given_y,
        "q": q,
    }


@pytest.mark.parametrize("matching", ["attitude", "attitude_rate"])
def test_one_pass_and_smoother_equal_dense_generalised_least_squares(matching: str) -> None:
    cfg = cfg_with(*SHORT, f"filter.matching={matching}")
    data = simulate(cfg, 11, [3])
    params = FilterParams.from_config(cfg)
    epochs = covariance_epochs(cfg)
    sol = solve_batch(params, data, epochs, max_iterations=1)
    ref = _dense_reference(cfg, data, params)
    sd = np.sqrt(np.diag(ref["cov_y"]))
    # the Gauss–Newton step and the parameter covariance
    np.testing.assert_allclose(sol.last_step[0] / sd, ref["step"] / sd, atol=1e-6)
    corr = ref["cov_y"] / np.outer(sd, sd)
    np.testing.assert_allclose(sol.cov_y[0] / np.outer(sd, sd), corr, atol=1e-7)
    # the smoothed nuisance at the linearisation point, at every epoch
    xi = _log(ref["q"], sol.est[0, :, 0:4])
    np.testing.assert_allclose(
        xi / params.sigma_a, ref["nuis_given_y"][:, 0:3] / params.sigma_a, atol=1e-6
    )
    bias = sol.est[0, :, 4:7]
    np.testing.assert_allclose(bias / 1e-9, ref["nuis_given_y"][:, 3:6] / 1e-9, atol=1e-6)
    # the error covariance at the sampled epochs: x_k = [S_k Δy + ξ_k, Δb + β_k, Δp]
    assert epochs.size >= 4
    for j, k in enumerate(epochs):
        t_map = np.zeros((15, ref["post_cov"].shape[0]))
        t_map[0:3, :15] = ref["sens"][k]
        t_map[0:3, 15:] = ref["nuis"][k, 0:3]
        t_map[3:6, 3:6] = np.eye(3)
        t_map[3:6, 15:] = ref["nuis"][k, 3:6]
        t_map[6:15, 6:15] = np.eye(9)
        want = t_map @ ref["post_cov"] @ t_map.T
        got = sol.cov[0, j]
        dsd = np.sqrt(np.diag(want))
        np.testing.assert_allclose(got / np.outer(dsd, dsd), want / np.outer(dsd, dsd), atol=1e-6)


def test_iterates_to_a_fixed_point_and_fits_the_contract() -> None:
    cfg = cfg_with(*SHORT, "scenario.duration_s=400")
    data = simulate(cfg, 3, 4)
    out = run_batch(cfg, data)
    validate_output(out, "batch", 4, data.n_epochs, covariance_epochs(cfg).size)
    assert not out.diverged.any()
    assert np.all(out.logs["converged"]) and np.all(out.logs["passes"] <= 6)
    assert out.kappa is None
    # reported calibration is constant over the run, the bias follows its walk
    assert np.all(out.est[:, :, 7:16] == out.est[:, :1, 7:16])
    assert np.ptp(out.est[:, :, 4:7], axis=1).max() > 0.0
    # whitened residuals at the solution: χ² per row near 1
    chi2_per_row = out.logs["chi2"] / out.logs["rows"]
    assert np.all(np.abs(chi2_per_row - 1.0) < 0.1), chi2_per_row


def _band(dof: int, level: float) -> tuple[float, float]:
    lo, hi = stats.chi2.ppf([level / 2, 1 - level / 2], dof) / dof
    return float(lo), float(hi)


@pytest.mark.slow
def test_rms_at_last_epoch_is_at_the_crlb_and_covariance_is_consistent() -> None:
    """Truth drawn from the prior, constant calibration (the model the batch assumes): at the
    end of the run the RMS over 100 trials is at the CRLB, state by state (χ² band of the
    squared RMS ratio, 1 % over the 15 states together: about [0.79, 1.24] for the ratio); the
    batch's own covariance passes NEES; and its final estimate is the Kalman filter's with the
    same model (the two solve the same linear-Gaussian problem, so they must agree far more
    closely than either agrees with the truth)."""
    trials = 100
    cfg = cfg_with("scenario.randomize_truth=true", "filter.qp0=1e-20")
    data = simulate(cfg, 2024, trials)
    out = run_batch(cfg, data)
    assert not out.diverged.any()
    err = state_errors(out.est, data.q_true, data.bias, data.calib)
    bound = crlb(cfg).bound[-1]
    ratio2 = np.mean(err[:, -1] ** 2, axis=0) / bound**2
    lo, hi = _band(trials, 0.01 / 15)
    assert np.all((ratio2 > lo) & (ratio2 < hi)), np.round(np.sqrt(ratio2), 3)
    # NEES of the reported covariance at the sampled epochs
    epochs = covariance_epochs(cfg)
    avg = nees(err[:, epochs], out.cov).mean(axis=0) / 15  # per state
    nlo, nhi = _band(15 * trials, 0.01)
    inside = (avg > nlo) & (avg < nhi)
    assert inside.mean() >= 0.95, f"{inside.mean():.3f} inside [{nlo:.2f}, {nhi:.2f}]"
    # the same end point as the filter with the same model, to a small fraction of the bound
    kf = run_kf(cfg, data)
    diff = state_errors(
        out.est[:, -1:], kf.est[:, -1, 0:4][:, None], kf.est[:, -1:, 4:7], kf.est[:, -1:, 7:16]
    )[:, 0]
    assert np.sqrt(np.mean(diff**2, axis=0) / bound**2).max() < 0.1
