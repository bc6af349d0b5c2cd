"""The IMM bank and the strong-tracking (fading) filter: their math worked by hand on scalar
problems, the invariants of the transfer-alignment versions, batch independence, and runs on
every preset."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.core.config import ConfigError
from qkf.core.so3 import quat_exp, quat_log, quat_mul
from qkf.transfer_alignment.adaptive import FadingConfig, ImmConfig
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods import METHODS, validate_output
from qkf.transfer_alignment.methods.base import action_values, new_filter
from qkf.transfer_alignment.methods.fading import (
    attitude_innovation,
    fading_factor,
    fading_filter,
    forget_innovation_covariance,
    prior_cap,
    run_fading,
    strong_tracking_step,
    transition,
)
from qkf.transfer_alignment.methods.imm import imm_filter, run_imm, transition_matrix
from qkf.transfer_alignment.model import calibration_matrix, discretize
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import cfg_with
from tests.imm_numpy import (
    mix_bank,
    mix_moments,
    mixing_probabilities,
    unit_calibration_noise,
    update_model_probabilities,
)
from tests.mmae_numpy import update_log_weights

PRESETS = ["paper", "attitude_only", "thermal_drift", "thermal_snap", "noise_mismatch"]


# ---- IMM: generic algebra ------------------------------------------------------------------------


def test_transition_matrix_uniform_and_neighbours() -> None:
    pi = transition_matrix(4, 0.91, "uniform")
    np.testing.assert_allclose(pi.sum(axis=1), 1.0)
    np.testing.assert_allclose(np.diag(pi), 0.91)
    np.testing.assert_allclose(pi[0, 1:], 0.03)  # (1 − 0.91) / 3
    nb = transition_matrix(4, 0.9, "neighbours")
    np.testing.assert_allclose(nb.sum(axis=1), 1.0)
    np.testing.assert_allclose(nb[0], [0.9, 0.1, 0.0, 0.0])  # an end: all to its one neighbour
    np.testing.assert_allclose(nb[1], [0.05, 0.9, 0.05, 0.0])
    np.testing.assert_allclose(nb[3], [0.0, 0.0, 0.1, 0.9])
    with pytest.raises(ValueError):
        transition_matrix(1, 0.9)


def test_imm_cycle_on_two_scalar_models_by_hand() -> None:
    """μ = (0.6, 0.4), Π = [[0.9, 0.1], [0.2, 0.8]], x̂ = (1, 3), P = (0.5, 2).

    c̄_1 = 0.9·0.6 + 0.2·0.4 = 0.62,    c̄_2 = 0.1·0.6 + 0.8·0.4 = 0.38
    μ_1|1 = 0.54/0.62 = 27/31,  μ_2|1 = 0.08/0.62 = 4/31
    μ_1|2 = 0.06/0.38 = 3/19,   μ_2|2 = 0.32/0.38 = 16/19
    x̂0_1 = (27·1 + 4·3)/31 = 39/31
    P0_1 = (27·0.5 + 4·2)/31 + μ_1|1 μ_2|1 (x̂_1 − x̂_2)² = 21.5/31 + 432/961 = 1.1430801...
    x̂0_2 = (3·1 + 16·3)/19 = 51/19
    P0_2 = (3·0.5 + 16·2)/19 + (3/19)(16/19)·4 = 33.5/19 + 192/361 = 2.2950138...
    (for two models Σ_i μ_i|j (x̂_i − x̂0_j)² = μ_1|j μ_2|j (x̂_1 − x̂_2)²)
    Likelihoods Λ = (2, 1): μ ∝ (2·0.62, 1·0.38) = (1.24, 0.38) → (62/81, 19/81).
    """
    mu = np.array([0.6, 0.4])
    pi = np.array([[0.9, 0.1], [0.2, 0.8]])
    c_bar, mix = mixing_probabilities(mu, pi)
    np.testing.assert_allclose(c_bar, [0.62, 0.38])
    np.testing.assert_allclose(mix, [[27 / 31, 3 / 19], [4 / 31, 16 / 19]])
    x0, p0 = mix_moments(np.array([[1.0], [3.0]]), np.array([[[0.5]], [[2.0]]]), mix)
    np.testing.assert_allclose(x0[:, 0], [39 / 31, 51 / 19])
    np.testing.assert_allclose(
        p0[:, 0, 0], [21.5 / 31 + 432 / 961, 33.5 / 19 + 192 / 361], rtol=1e-14
    )
    np.testing.assert_allclose(p0[:, 0, 0], [1.1430801, 2.2950138], rtol=1e-7)
    new = update_model_probabilities(c_bar, np.log([2.0, 1.0]))
    np.testing.assert_allclose(new, [62 / 81, 19 / 81])
    # a diverged model (ℓ = −inf) gets μ = 0; no live model at all: zeros
    np.testing.assert_allclose(update_model_probabilities(c_bar, np.array([-np.inf, 0.0])), [0, 1])
    np.testing.assert_array_equal(update_model_probabilities(c_bar, np.full(2, -np.inf)), [0, 0])


def test_mix_moments_of_vector_states_match_the_definition() -> None:
    rng = np.random.default_rng(3)
    b, n_mod, n = 2, 3, 4
    x = rng.normal(size=(b, n_mod, n)) + 1e3  # an offset: the centring must not lose digits
    half = rng.normal(size=(b, n_mod, n, n))
    cov = half @ np.swapaxes(half, -1, -2)
    _, mix = mixing_probabilities(rng.dirichlet(np.ones(n_mod), size=b), transition_matrix(3, 0.7))
    x0, p0 = mix_moments(x, cov, mix)
    for t in range(b):
        for j in range(n_mod):
            xj = sum(mix[t, i, j] * x[t, i] for i in range(n_mod))
            pj = sum(
                mix[t, i, j] * (cov[t, i] + np.outer(x[t, i] - xj, x[t, i] - xj))
                for i in range(n_mod)
            )
            np.testing.assert_allclose(x0[t, j], xj, rtol=1e-14)
            np.testing.assert_allclose(p0[t, j], pj, rtol=1e-9, atol=1e-9)


def test_imm_with_identity_switching_is_the_mmae_recursion_without_floor() -> None:
    rng = np.random.default_rng(5)
    n_mod = 5
    mu = np.full((3, n_mod), 1.0 / n_mod)
    log_w = np.log(mu)
    pi = np.eye(n_mod)
    for k in range(40):
        ll = rng.normal(scale=3.0, size=(3, n_mod))
        if k == 20:
            ll[1, 2] = -np.inf  # a model diverges
        c_bar, mix = mixing_probabilities(mu, pi)
        np.testing.assert_array_equal(mix, np.broadcast_to(np.eye(n_mod), mix.shape))
        mu = update_model_probabilities(c_bar, ll)
        log_w = update_log_weights(log_w, ll, floor=0.0)
        np.testing.assert_allclose(mu, np.exp(log_w), rtol=1e-12, atol=1e-300)
    assert mu[1, 2] == 0.0


# ---- IMM: the transfer-alignment bank ----------------------------------------------------------


def test_quaternion_helpers_match_scipy() -> None:
    r, s = Rotation.random(20, random_state=1), Rotation.random(20, random_state=2)
    np.testing.assert_allclose(quat_mul(r.as_quat(), s.as_quat()), (r * s).as_quat(), atol=1e-15)
    phi = (
        np.random.default_rng(0).normal(size=(20, 3))
        * np.repeat([1e-10, 1e-5, 0.3, 0.8], 5)[:, None]
    )
    np.testing.assert_allclose(quat_exp(phi), Rotation.from_rotvec(phi).as_quat(), atol=1e-15)
    q = Rotation.from_rotvec(phi).as_quat()
    q[::2] *= -1.0  # q and −q are the same rotation
    np.testing.assert_allclose(quat_log(q), phi, rtol=1e-12, atol=1e-20)


@pytest.mark.parametrize("rate_deg_s", [0.06, 1.0, 5.0])
def test_unit_calibration_noise_is_the_kappa_part_of_q_d(rate_deg_s: float) -> None:
    rng = np.random.default_rng(7)
    w = rng.normal(size=(4, 3))
    w *= np.deg2rad(rate_deg_s) / np.linalg.norm(w, axis=1, keepdims=True)
    p = rng.normal(size=(4, 9)) * 1e-3
    a = np.linalg.inv(np.eye(3) + calibration_matrix(p))
    # Q_d is affine in q_p: Q_d(q) − Q_d(0) = q U
    _, q1 = discretize(w, a, 1.0, 1e-7, 1e-9, 2e-14, nodes=8)
    _, q0 = discretize(w, a, 1.0, 1e-7, 1e-9, 0.0, nodes=8)
    ref = (q1 - q0) / 2e-14
    u = unit_calibration_noise(1.0, w, p)
    scale = np.abs(ref).max(axis=(1, 2), keepdims=True)
    assert np.max(np.abs(u - ref) / scale) < 1e-9
    np.testing.assert_allclose(u[:, 6:, 6:], np.broadcast_to(np.eye(9), (4, 9, 9)))


def _bank_after_one_epoch() -> tuple[Any, Any, np.ndarray, Any]:
    cfg = cfg_with("scenario.duration_s=10")
    data = simulate(cfg, 0, 2)
    kappas = action_values(cfg)
    n_act = kappas.size
    bank = new_filter(cfg, data, n_copies=n_act)
    rec = bank.step_data(
        SimpleNamespace(
            gyro=np.repeat(data.gyro, n_act, axis=0),
            ads_q=np.repeat(data.ads_q, n_act, axis=0),
            ads_rate=np.repeat(data.ads_rate, n_act, axis=0),
            has_meas=data.has_meas,
        ),
        0,
        1,
        kappa=np.tile(kappas, 2),
    )
    return cfg, bank, kappas, rec


def test_mixing_models_that_differ_only_in_their_last_kappa_changes_nothing() -> None:
    """From one start, one epoch: the models differ only by κ_i q_p0 U in P. Mixing removes
    each model's own calibration noise and adds it back, so whatever μ, nothing changes."""
    cfg, bank, kappas, rec = _bank_after_one_epoch()
    n_act = kappas.size
    d = bank.params.p0_sigma
    before = (bank.q_hat.copy(), bank.b_hat.copy(), bank.p_hat.copy(), bank.P / np.outer(d, d))
    rows = np.arange(2) * n_act
    unit_q = unit_calibration_noise(cfg.scenario.dt_s, rec.rate[rows, 0], bank.p_hat[rows])
    mu = np.random.default_rng(1).dirichlet(np.ones(n_act), size=2)
    trans = transition_matrix(n_act, 0.8)
    c_bar = mix_bank(bank.copy(), mu, trans, kappas, unit_q, np.ones(2, dtype=bool))
    np.testing.assert_allclose(c_bar, mu @ trans)
    mixed = bank.copy()
    mix_bank(mixed, mu, trans, kappas, unit_q, np.ones(2, dtype=bool))
    np.testing.assert_allclose(mixed.q_hat, before[0], atol=1e-15)
    np.testing.assert_allclose(mixed.b_hat, before[1], atol=1e-22)
    np.testing.assert_allclose(mixed.p_hat, before[2], atol=1e-18)
    np.testing.assert_allclose(mixed.P / np.outer(d, d), before[3], rtol=0, atol=1e-12)
    # without the swap of the calibration noise the models would be blurred
    naive = bank.copy()
    mix_bank(naive, mu, trans, kappas, np.zeros_like(unit_q), np.ones(2, dtype=bool))
    assert np.max(np.abs(naive.P / np.outer(d, d) - before[3])) > 1e-9


def test_mixing_spreads_differing_estimates_into_the_covariance() -> None:
    """Trial 0: model 1 believes s_x higher by δ = 1e-4, model 2 the attitude turned by
    ε = 2e-5 rad about z. With Π rows all 1/A every μ_i|j = w = 1/A, so every model gets
    s_x + w δ, the attitude turned by w ε, and the spreads w (1 − w) δ² and w (1 − w) ε²
    (one model offset by δ: Σ_i w (x_i − x̄)² = w(1 − w)² δ² + (A − 1) w (w δ)² = w (1 − w) δ²).
    Trial 1 is left as it was."""
    cfg, bank, kappas, rec = _bank_after_one_epoch()
    n_act = kappas.size
    rows = np.arange(2) * n_act
    unit_q = unit_calibration_noise(cfg.scenario.dt_s, rec.rate[rows, 0], bank.p_hat[rows])
    q_before, p_hat_before, cov_before = bank.q_hat.copy(), bank.p_hat.copy(), bank.P
    delta, eps = 1e-4, 2e-5
    bank.p_hat[1, 0] += delta
    bank.q_hat[2] = (
        Rotation.from_quat(bank.q_hat[2]) * Rotation.from_rotvec([0, 0, eps])
    ).as_quat()
    w = 1.0 / n_act
    trans = transition_matrix(n_act, w)  # every row (1/A, …, 1/A)
    mix_bank(bank, np.full((2, n_act), w), trans, kappas, unit_q, np.ones(2, dtype=bool))
    t0 = slice(0, n_act)
    np.testing.assert_allclose(bank.p_hat[t0, 0] - p_hat_before[t0, 0], w * delta, rtol=1e-9)
    turn = (Rotation.from_quat(q_before[t0]).inv() * Rotation.from_quat(bank.q_hat[t0])).as_rotvec()
    np.testing.assert_allclose(turn, np.tile([0.0, 0.0, w * eps], (n_act, 1)), atol=1e-15)
    extra = bank.P[t0] - cov_before[t0]
    np.testing.assert_allclose(extra[:, 6, 6], w * (1 - w) * delta**2, rtol=1e-6)
    np.testing.assert_allclose(extra[:, 2, 2], w * (1 - w) * eps**2, rtol=1e-6)
    np.testing.assert_allclose(extra[:, 2, 6], -(w**2) * delta * eps, rtol=1e-6)
    d = bank.params.p0_sigma
    t1 = slice(n_act, 2 * n_act)
    np.testing.assert_allclose(bank.p_hat[t1], p_hat_before[t1], rtol=0, atol=1e-18)
    np.testing.assert_allclose(
        bank.P[t1] / np.outer(d, d), cov_before[t1] / np.outer(d, d), rtol=0, atol=1e-12
    )
    assert not bank.diverged.any()


def test_imm_settings_are_the_config_section() -> None:
    """``adaptive.imm`` is what run_imm uses: defaults and validation live in ImmConfig only."""
    assert load_config("paper").adaptive.imm == ImmConfig()
    cfg = cfg_with(
        "adaptive.imm.p_stay=0.9", "adaptive.imm.switching=neighbours", "scenario.duration_s=5"
    )
    prm = cfg.adaptive.imm
    assert (prm.p_stay, prm.switching, prm.mix_every) == (0.9, "neighbours", 1)
    assert "p_stay = 0.9, neighbours switching" in run_imm(cfg, simulate(cfg, 0, 1)).notes["imm"]
    with pytest.raises(ConfigError, match=r"adaptive\.imm\.p_stay"):
        cfg_with("adaptive.imm.p_stay=1.0")
    with pytest.raises(ConfigError, match=r"adaptive\.imm\.mix_every"):
        cfg_with("adaptive.imm.mix_every=0")
    with pytest.raises(ValueError, match="p_stay"):
        ImmConfig(p_stay=1.0)


def test_imm_output_contract_and_probabilities() -> None:
    cfg = cfg_with("scenario.duration_s=320")
    data = simulate(cfg, 2, 2)
    out = run_imm(cfg, data)
    validate_output(out, "imm", 2, data.n_epochs)
    probs = out.logs["probabilities"]
    kappas = action_values(cfg)
    np.testing.assert_allclose(probs.sum(axis=-1), 1.0)
    assert out.kappa is not None
    np.testing.assert_allclose(out.kappa, np.exp(probs @ np.log(kappas)))
    np.testing.assert_allclose(out.logs["kappa_arith"], probs @ kappas)
    # the interaction keeps every model alive (1 − p_stay spread over the others each epoch)
    assert probs.min() > 1e-3
    assert np.isfinite(out.est).all() and not out.diverged.any()
    # combined estimate: at the truth's level of error, like the plain filter
    kf = METHODS["kf"](cfg, data)
    np.testing.assert_allclose(out.est[:, -1, 4:], kf.est[:, -1, 4:], rtol=0, atol=2e-5)


def test_imm_with_mixing_every_few_epochs_runs_and_differs() -> None:
    cfg = cfg_with("scenario.duration_s=120")
    data = simulate(cfg, 2, 1)
    every = imm_filter(cfg, data, ImmConfig(mix_every=1))
    sparse = imm_filter(cfg, data, ImmConfig(mix_every=7))
    validate_output(sparse, "imm", 1, data.n_epochs)
    assert np.isfinite(sparse.est).all()
    assert not np.array_equal(every.est, sparse.est)


def test_imm_trial_does_not_depend_on_its_batch() -> None:
    cfg = cfg_with("scenario.duration_s=100")
    three = run_imm(cfg, simulate(cfg, 0, [0, 1, 2]))
    alone = run_imm(cfg, simulate(cfg, 0, [1]))
    np.testing.assert_array_equal(three.est[1], alone.est[0])
    assert three.kappa is not None and alone.kappa is not None
    np.testing.assert_array_equal(three.kappa[1], alone.kappa[0])
    np.testing.assert_array_equal(three.logs["probabilities"][1], alone.logs["probabilities"][0])


# ---- fading: generic algebra -------------------------------------------------------------------


def test_innovation_covariance_with_forgetting() -> None:
    nu0, nu1 = np.array([1.0, 2.0]), np.array([0.5, -1.0])
    v0 = forget_innovation_covariance(None, nu0, 0.9)
    np.testing.assert_allclose(v0, [[1.0, 2.0], [2.0, 4.0]])  # V_0 = ν_0 ν_0ᵀ
    v1 = forget_innovation_covariance(v0, nu1, 0.9)
    np.testing.assert_allclose(v1, (0.9 * v0 + np.outer(nu1, nu1)) / 1.9)


def test_strong_tracking_on_a_scalar_problem_by_hand() -> None:
    """x_{k+1} = x_k + w (Q = 0.1), z = x + v (R = 0.5); ρ = 0.95, β = 1; x̂⁺ = 0, P⁺ = 1.

    k = 1, z = 3:   ν = 3, V = 9, N = 9 − 0.5 − 0.1 = 8.4, M = 1, λ = 8.4,
                    P⁻ = 8.4 + 0.1 = 8.5, K = 8.5/9, x̂ = 2.8333333, P⁺ = 8.5/18 = 0.4722222
    k = 2, z = 2.9: ν = 0.0666667, V = (0.95·9 + ν²)/1.95 = 4.3868946, N = 3.7868946,
                    M = 0.4722222, λ = 8.0193062, P⁻ = 3.8868946, K = 0.8860242,
                    x̂ = 2.8924016, P⁺ = 0.4430121
    k = 3, z = 3.2, β = 10: N = V − 5 − 0.1 < 0 → λ = 1 (the ordinary Kalman step)
    """
    x, p = np.zeros(1), np.ones((1, 1))
    one, q, r = np.eye(1), np.array([[0.1]]), np.array([[0.5]])
    x, p, v, lam = strong_tracking_step(x, p, None, np.array([3.0]), one, q, one, r, 0.95, 1.0)
    assert lam == pytest.approx(8.4)
    np.testing.assert_allclose(v, [[9.0]])
    np.testing.assert_allclose([x[0], p[0, 0]], [2.8333333333, 8.5 / 18], rtol=1e-10)
    x, p, v, lam = strong_tracking_step(x, p, v, np.array([2.9]), one, q, one, r, 0.95, 1.0)
    assert v[0, 0] == pytest.approx(4.3868945869)
    assert lam == pytest.approx(8.0193061840)
    np.testing.assert_allclose([x[0], p[0, 0]], [2.8924016106, 0.4430120795], rtol=1e-9)
    x_kf = x + (p[0, 0] + 0.1) / (p[0, 0] + 0.6) * (3.2 - x)
    x, p, v, lam = strong_tracking_step(x, p, v, np.array([3.2]), one, q, one, r, 0.95, 10.0)
    assert lam == 1.0
    np.testing.assert_allclose(x, x_kf)


def test_fading_factor_and_prior_cap() -> None:
    eye = np.eye(2)
    # tr N = tr(4I − 1.5·I − 0.5·I) = 4, tr M = 0.5 → λ = 8;  β = 3: tr N = 1, λ = 2;
    # β = 4: tr N = −1 < 0 → λ = 1
    assert fading_factor(4 * eye, eye, 0.5 * eye, 0.25 * eye, 1.5) == pytest.approx(8.0)
    assert fading_factor(4 * eye, eye, 0.5 * eye, 0.25 * eye, 3.0) == pytest.approx(2.0)
    assert fading_factor(4 * eye, eye, 0.5 * eye, 0.25 * eye, 4.0) == 1.0
    # room to the prior: (10 − 4)/2 = 3 and (1 − 0.5)/0.1 = 5 → λ_cap = 1 + 3
    p_pred, php, p0 = np.diag([4.0, 0.5]), np.diag([2.0, 0.1]), np.array([10.0, 1.0])
    assert prior_cap(p_pred, php, p0) == pytest.approx(4.0)
    assert prior_cap(np.diag([12.0, 0.5]), php, p0) == 1.0  # already above the prior


# ---- fading: the transfer-alignment filter ------------------------------------------------------


def test_transition_is_the_models() -> None:
    rng = np.random.default_rng(2)
    w = rng.normal(size=(3, 3)) * 0.02
    p = rng.normal(size=(3, 9)) * 1e-3
    a = np.linalg.inv(np.eye(3) + calibration_matrix(p))
    phi_ref, _ = discretize(w, a, 0.7, 1e-7, 1e-9, 1e-14)
    np.testing.assert_allclose(transition(w, p, 0.7), phi_ref, rtol=1e-13, atol=1e-16)


def test_attitude_innovation_is_the_filters() -> None:
    cfg = cfg_with("scenario.duration_s=20")
    data = simulate(cfg, 1, 2)
    kf = new_filter(cfg, data)
    for k in range(20):
        nu = attitude_innovation(kf.q_hat, data.ads_q[:, k])
        rec = kf.step_data(data, k, k + 1)
        np.testing.assert_allclose(nu, rec.innov[:, 0, 0:3], rtol=0, atol=1e-15)


def test_fading_settings_are_the_config_section() -> None:
    """``adaptive.fading`` is what run_fading uses: defaults and validation in FadingConfig."""
    assert load_config("paper").adaptive.fading == FadingConfig()
    cfg = cfg_with("adaptive.fading.softening=2.5", "scenario.duration_s=5")
    prm = cfg.adaptive.fading
    assert (prm.forgetting, prm.softening) == (0.95, 2.5)
    assert "β = 2.5" in run_fading(cfg, simulate(cfg, 0, 1)).notes["fading"]
    with pytest.raises(ConfigError, match=r"adaptive\.fading\.softening"):
        cfg_with("adaptive.fading.softening=0.5")
    with pytest.raises(ConfigError, match=r"adaptive\.fading\.lambda_max"):
        cfg_with("adaptive.fading.lambda_max=0.9")
    with pytest.raises(ValueError, match="softening"):
        FadingConfig(softening=0.5)


def test_fading_that_never_fires_is_the_plain_filter() -> None:
    cfg = cfg_with("scenario.duration_s=300")
    data = simulate(cfg, 4, 2)
    out = fading_filter(cfg, data, FadingConfig(softening=1e9))
    validate_output(out, "fading", 2, data.n_epochs)
    assert np.all(out.logs["lambda"] == 1.0)
    assert out.kappa is not None
    np.testing.assert_array_equal(out.kappa, 1.0)
    kf = METHODS["kf"](cfg, data)
    # the same filter to rounding: fading's compiled code and the kernel are separate copies
    # of the arithmetic, each optimised in its own module, and their last bits differ
    # (docs/performance.md). Scale: 1 for q̂, the prior sigmas for b̂ and p̂.
    scale = np.concatenate([np.ones(4), new_filter(cfg, data).params.p0_sigma[3:]])
    np.testing.assert_allclose(out.est / scale, kf.est / scale, rtol=1e-9, atol=1e-12)


def test_fading_fires_inflates_and_stays_bounded() -> None:
    """β = 1: noise alone triggers λ > 1 at a good share of the epochs (the attitude innovation
    is dominated by the ADS noise); the prior cap keeps the filter from diverging."""
    cfg = cfg_with("scenario.duration_s=400")
    data = simulate(cfg, 4, 2)
    out = fading_filter(cfg, data, FadingConfig(softening=1.0, lambda_max=1e3))
    validate_output(out, "fading", 2, data.n_epochs)
    lam = out.logs["lambda"]
    assert 0.05 < np.mean(lam > 1.0) < 0.9
    assert lam.max() > 2.0 and lam.min() == 1.0
    assert not out.diverged.any() and np.isfinite(out.est).all()
    kappas = action_values(cfg)
    assert out.kappa is not None
    assert np.all((out.kappa >= kappas.min()) & (out.kappa <= kappas.max()))
    assert np.all(out.logs["kappa_equiv"] >= 1.0)
    assert np.max(out.logs["kappa_equiv"]) > kappas.max()  # the unclipped equivalent


def test_fading_trial_does_not_depend_on_its_batch() -> None:
    cfg = cfg_with("scenario.duration_s=200")
    prm = FadingConfig(softening=1.5)  # so that it fires
    three = fading_filter(cfg, simulate(cfg, 0, [0, 1, 2]), prm)
    alone = fading_filter(cfg, simulate(cfg, 0, [1]), prm)
    assert np.any(three.logs["lambda"] > 1.0)
    np.testing.assert_array_equal(three.est[1], alone.est[0])
    np.testing.assert_array_equal(three.logs["lambda"][1], alone.logs["lambda"][0])


# ---- both, on every preset ----------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("method", [run_imm, run_fading], ids=["imm", "fading"])
def test_runs_on_every_preset_without_divergence(preset: str, method: Any) -> None:
    cfg = load_config(preset, ["scenario.duration_s=600"])
    data = simulate(cfg, 11, 4)
    out = validate_output(method(cfg, data), method.__name__, 4, data.n_epochs)
    assert not out.diverged.any()
    assert np.isfinite(out.est).all()
    assert out.kappa is not None and np.all(np.isfinite(out.kappa) & (out.kappa > 0))


@pytest.mark.slow
def test_fading_survives_a_badly_underestimated_measurement_noise() -> None:
    """True ADS noise 10″, assumed 3″: λ fires almost every epoch; the prior cap holds P."""
    cfg = load_config(
        "noise_mismatch", ["scenario.duration_s=600", "scenario.ads.attitude_sigma_arcsec=10"]
    )
    out = run_fading(cfg, simulate(cfg, 0, 2))
    assert np.mean(out.logs["lambda"] > 1.0) > 0.5
    assert not out.diverged.any() and np.isfinite(out.est).all()
