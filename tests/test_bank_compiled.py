"""The compiled κ bank of MMAE and IMM (methods/bank_compiled.py) against its numpy references:
each piece on random inputs (dead models and trials included), the bank's filter against the
kernel bit for bit, and both methods end to end against their numpy drivers."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from qkf.transfer_alignment.adaptive import ImmConfig
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.methods.bank_compiled import (
    imm_probabilities,
    mmae_log_weights,
    run_bank,
)
from qkf.transfer_alignment.methods.base import MethodOutput, action_values, new_filter
from qkf.transfer_alignment.methods.covariance import CovarianceRecorder
from qkf.transfer_alignment.methods.imm import imm_filter, transition_matrix
from qkf.transfer_alignment.methods.mmae import run_mmae
from qkf.transfer_alignment.scenario import ScenarioData, simulate
from tests.bank_reference import (
    combine_compiled,
    mix_bank_compiled,
    mixture_covariance_compiled,
    unit_calibration_noise_compiled,
)
from tests.conftest import cfg_with
from tests.imm_numpy import (
    imm_filter_reference,
    mix_bank,
    unit_calibration_noise,
    update_model_probabilities,
)
from tests.mmae_numpy import combine, mixture_covariance, run_mmae_reference, update_log_weights

# ---- U ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dt", [0.1, 1.0])
@pytest.mark.parametrize("rate_deg_s", [0.0, 0.06, 1.0, 5.0])
def test_unit_noise_is_the_numpy_reference(dt: float, rate_deg_s: float) -> None:
    rng = np.random.default_rng(11)
    w = rng.normal(size=(5, 3))
    w *= np.deg2rad(rate_deg_s) / np.linalg.norm(w, axis=1, keepdims=True)
    p = rng.normal(size=(5, 9)) * 1e-3
    p[0] = 0.0
    ref = unit_calibration_noise(dt, w, p)
    u = unit_calibration_noise_compiled(dt, w, p)
    scale = np.abs(ref).max(axis=(1, 2), keepdims=True)
    assert np.max(np.abs(u - ref) / scale) < 1e-14
    # the attitude blocks are far below U_pp = Δt I: they are checked on their own scale
    for blk in (np.s_[:, 0:3, 0:3], np.s_[:, 0:3, 6:15]):
        assert np.max(np.abs(u[blk] - ref[blk])) <= 1e-14 * np.abs(ref[blk]).max() + 1e-300
    np.testing.assert_array_equal(u, np.swapaxes(u, 1, 2))


# ---- mixing -------------------------------------------------------------------------------------


def _differing_bank(n_trials: int) -> tuple[TransferAlignmentKF, np.ndarray, np.ndarray, float]:
    """A bank after 20 epochs whose models then differ in attitude, bias and calibration."""
    cfg = cfg_with("scenario.duration_s=30")
    data = simulate(cfg, 0, n_trials)
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
        20,
        kappa=np.tile(kappas, n_trials),
    )
    rng = np.random.default_rng(4)
    rows = bank.n_trials
    turn = Rotation.from_rotvec(rng.normal(size=(rows, 3)) * 2e-5)
    bank.q_hat[:] = (Rotation.from_quat(bank.q_hat) * turn).as_quat()
    bank.b_hat += rng.normal(size=(rows, 3)) * 1e-8
    bank.p_hat += rng.normal(size=(rows, 9)) * 1e-5
    first = np.arange(n_trials) * n_act
    unit_q = unit_calibration_noise(cfg.scenario.dt_s, rec.rate[first, -1], bank.p_hat[first])
    return bank, kappas, unit_q, cfg.scenario.dt_s


@pytest.mark.parametrize("switching", ["uniform", "neighbours"])
def test_compiled_mixing_is_mix_bank(switching: str) -> None:
    """Trial 0: a diverged model and one with a non-finite attitude; trial 1 (neighbours: the
    first three models without probability, so c̄ = 0 for the first two); trial 2: not live;
    trial 3: all its models diverged."""
    bank, kappas, unit_q, _ = _differing_bank(4)
    n_act = kappas.size
    rng = np.random.default_rng(9)
    mu = rng.dirichlet(np.ones(n_act), size=4)
    bank.diverged[3] = True
    bank.q_hat[5] = np.nan
    bank.diverged[3 * n_act : 4 * n_act] = True
    if switching == "neighbours":
        mu[1, 0:3] = 0.0
        mu[1] /= mu[1].sum()
    live = np.array([True, True, False, True])
    trans = transition_matrix(n_act, 0.85, switching)  # type: ignore[arg-type]
    ref, cmp = bank.copy(), bank.copy()
    c_ref = mix_bank(ref, mu, trans, kappas, unit_q, live)
    c_cmp = mix_bank_compiled(cmp, mu, trans, kappas, unit_q, live)
    np.testing.assert_allclose(c_cmp, c_ref, rtol=1e-14, atol=1e-16)
    np.testing.assert_array_equal(cmp.diverged, ref.diverged)
    assert not cmp.diverged[: 2 * n_act].any()  # the live trials restarted every model
    mixed = slice(0, 2 * n_act)
    # unit quaternions: a few units in the last place (the compiled mixing fuses multiply-adds
    # and reassociates sums; its own rounding is fixed, whatever the cache: docs/performance.md)
    np.testing.assert_allclose(cmp.q_hat[mixed], ref.q_hat[mixed], rtol=0, atol=1e-15)
    np.testing.assert_allclose(cmp.b_hat[mixed], ref.b_hat[mixed], rtol=1e-13, atol=1e-22)
    np.testing.assert_allclose(cmp.p_hat[mixed], ref.p_hat[mixed], rtol=1e-13, atol=1e-19)
    d = bank.params.p0_sigma
    dd = np.outer(d, d)
    # P/dd is of order one: a few units in the last place
    np.testing.assert_allclose(
        cmp.P[mixed] / dd, ref.P[mixed] / dd, rtol=0, atol=1e-14 * np.abs(ref.P / dd).max()
    )
    # the models did mix: they moved towards each other
    assert np.abs(cmp.p_hat[mixed] - bank.p_hat[mixed]).max() > 1e-7
    # trials that are not mixed are left exactly as they were
    rest = slice(2 * n_act, 4 * n_act)
    for name in ("q_hat", "b_hat", "p_hat", "_pt", "diverged"):
        np.testing.assert_array_equal(getattr(cmp, name)[rest], getattr(bank, name)[rest])


# ---- model probabilities ------------------------------------------------------------------------


@pytest.mark.parametrize("floor", [0.0, 1e-3])
def test_mmae_log_weights_are_update_log_weights(floor: float) -> None:
    rng = np.random.default_rng(2)
    n_act = 7
    log_w = np.full((3, n_act), -np.log(n_act))
    mine = log_w.copy()
    scratch = np.empty(n_act)
    for k in range(60):
        ll = rng.normal(scale=4.0, size=(3, n_act)) + 70.0
        if k >= 20:
            ll[0, 2] = -np.inf  # a model diverges: out for good
        if k >= 40:
            ll[2] = -np.inf  # every model of trial 2 diverges: NaN weights
        with np.errstate(invalid="ignore"):  # trial 2 without a live model: NaN, as documented
            log_w = update_log_weights(log_w, ll, floor)
        for t in range(3):
            mmae_log_weights(mine[t], ll[t], floor, scratch)
        with np.errstate(invalid="ignore"):
            np.testing.assert_allclose(np.exp(mine), np.exp(log_w), rtol=1e-13, atol=1e-300)
    assert np.exp(mine[0, 2]) == 0.0
    assert np.isnan(mine[2]).all()


def test_imm_probabilities_are_update_model_probabilities() -> None:
    rng = np.random.default_rng(3)
    c_bar = rng.dirichlet(np.ones(6), size=5)
    ll = rng.normal(scale=3.0, size=(5, 6)) - 60.0
    c_bar[1, 2] = 0.0  # c̄ = 0: μ = 0
    ll[2, 4] = -np.inf  # a diverged model
    ll[3] = -np.inf  # no live model: all zeros
    ref = update_model_probabilities(c_bar, ll)
    out = np.empty(6)
    for t in range(5):
        total = imm_probabilities(c_bar[t], ll[t], out)
        np.testing.assert_allclose(out, ref[t], rtol=1e-13, atol=1e-300)
        assert total == (0.0 if t == 3 else 1.0)


# ---- combination and mixture covariance ---------------------------------------------------------


def _combine_scipy(est: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The combination as it was written with scipy's ``Rotation`` (before the so3 helpers)."""
    b, n_act, n, _ = est.shape
    out = np.empty((b, n, 16))
    out[..., 4:] = np.einsum("ban,banj->bnj", w, est[..., 4:])
    best = w.argmax(axis=1)
    q_ref = np.take_along_axis(est[..., 0:4], best[:, None, :, None], axis=1)[:, 0]
    ref = Rotation.from_quat(np.repeat(q_ref[:, None], n_act, axis=1).reshape(-1, 4))
    rel = (ref.inv() * Rotation.from_quat(est[..., 0:4].reshape(-1, 4))).as_rotvec()
    mean_rel = np.einsum("ban,banj->bnj", w, rel.reshape(b, n_act, n, 3))
    out[..., 0:4] = (
        (Rotation.from_quat(q_ref.reshape(-1, 4)) * Rotation.from_rotvec(mean_rel.reshape(-1, 3)))
        .as_quat()
        .reshape(b, n, 4)
    )
    return out


def _bank_estimates(rng: np.random.Generator, b: int, n_act: int, n: int) -> np.ndarray:
    """Estimates (B, A, n, 16): attitudes 0.2 arcsec to 0.3 rad apart, model 0 neutral (as a
    diverged model is combined)."""
    base = Rotation.random(b * n, random_state=5).as_quat().reshape(b, 1, n, 4)
    spread = rng.normal(size=(b, n_act, n, 3)) * np.geomspace(1e-6, 0.3, n_act)[:, None, None]
    est = np.empty((b, n_act, n, 16))
    rel = Rotation.from_rotvec(spread.reshape(-1, 3))
    est[..., 0:4] = (
        (Rotation.from_quat(np.broadcast_to(base, (b, n_act, n, 4)).reshape(-1, 4)) * rel)
        .as_quat()
        .reshape(b, n_act, n, 4)
    )
    est[..., 4:7] = rng.normal(size=(b, n_act, n, 3)) * 1e-6
    est[..., 7:] = rng.normal(size=(b, n_act, n, 9)) * 1e-3
    est[:, 0] = 0.0
    est[:, 0, :, 3] = 1.0
    return est


def _angle(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    return np.linalg.norm(
        (Rotation.from_quat(q1).inv() * Rotation.from_quat(q2)).as_rotvec(), axis=-1
    )


def test_combine_with_so3_and_compiled_is_the_scipy_combination() -> None:
    rng = np.random.default_rng(6)
    b, n_act, n = 3, 6, 40
    est = _bank_estimates(rng, b, n_act, n)
    w = rng.dirichlet(np.ones(n_act), size=(b, n)).transpose(0, 2, 1).copy()
    w[:, 0] = 0.0  # the neutral (diverged) model carries no weight
    w /= w.sum(axis=1, keepdims=True)
    w[0, 1:3, 0] = 0.5  # a tie: the first of the most probable is the reference
    w[0, 3:, 0] = 0.0
    ref = _combine_scipy(est, w)
    for out in (combine(est, w), combine_compiled(est, w)):
        for sl in (slice(4, 7), slice(7, 16)):  # weighted sums: a few units in the last place
            scale = np.abs(est[..., sl]).max()
            np.testing.assert_allclose(out[..., sl], ref[..., sl], rtol=0, atol=1e-15 * scale)
        np.testing.assert_allclose(np.linalg.norm(out[..., 0:4], axis=-1), 1.0, rtol=0, atol=3e-16)
        assert _angle(out[..., 0:4].reshape(-1, 4), ref[..., 0:4].reshape(-1, 4)).max() < 2e-15
    # the mean rotation is what it should be: Ĉ_refᵀ Ĉ = Exp(Σ w δθ) with Ĉ_ref = model 1
    q_ref = est[0, 1, 0, 0:4]
    rel = (Rotation.from_quat(q_ref).inv() * Rotation.from_quat(est[0, :, 0, 0:4])).as_rotvec()
    expect = Rotation.from_quat(q_ref) * Rotation.from_rotvec(w[0, :, 0] @ rel)
    assert _angle(combine_compiled(est, w)[0, 0, 0:4], expect.as_quat()) < 1e-15


def test_compiled_mixture_covariance_is_the_numpy_one() -> None:
    rng = np.random.default_rng(8)
    b, n_act = 5, 6
    est = _bank_estimates(rng, b, n_act, 1)[:, :, 0]
    w = rng.dirichlet(np.ones(n_act), size=b)
    half = rng.normal(size=(b, n_act, 15, 15)) * np.geomspace(1e-5, 1e-2, 15)
    cov = half @ np.swapaxes(half, -1, -2)
    w[1, 2] = 0.0  # not used: weight 0
    cov[2, 3, 4, 4] = np.nan  # not used: non-finite covariance
    est_mix = combine(est[:, :, None], w[:, :, None])[:, 0]
    est_mix[3] = np.nan  # no combined estimate: NaN
    w[4] = 0.0  # no model used: NaN
    ref = mixture_covariance(est, cov, w, est_mix)
    out = mixture_covariance_compiled(est, cov, w, est_mix)
    np.testing.assert_array_equal(np.isnan(out), np.isnan(ref))
    assert np.isnan(out[3]).all() and np.isnan(out[4]).all()
    scale = np.sqrt(np.einsum("bii->bi", ref[:3]))
    corr = np.abs(out[:3] - ref[:3]) / (scale[:, :, None] * scale[:, None, :])
    assert corr.max() < 1e-12
    np.testing.assert_array_equal(out, np.swapaxes(out, -1, -2))


# ---- the bank end to end ------------------------------------------------------------------------


def test_the_banks_filter_is_the_kernel_bit_for_bit() -> None:
    """The MMAE bank's models do not interact: after the run each row of the bank is exactly the
    filter run alone with its κ (the kernel's epoch routine, in the kernel's types)."""
    cfg = cfg_with("scenario.duration_s=40")
    data = simulate(cfg, 1, 2)
    kappas = action_values(cfg)
    n_act = kappas.size
    bank = new_filter(cfg, data, n_copies=n_act)
    rec = CovarianceRecorder(cfg, 2)
    run_bank(bank, data, kappas, rec.epochs, rec.cov)
    alone = new_filter(cfg, data, n_copies=n_act)
    alone.step(
        np.repeat(data.gyro, n_act, axis=0),
        np.repeat(data.ads_q, n_act, axis=0),
        np.repeat(data.ads_rate, n_act, axis=0),
        data.has_meas,
        np.tile(kappas, 2),
    )
    for name in ("q_hat", "b_hat", "p_hat", "_pt", "diverged"):
        np.testing.assert_array_equal(getattr(bank, name), getattr(alone, name))


def _break_trial(data: ScenarioData, trial: int, epoch: int) -> ScenarioData:
    """``data`` with a non-finite ADS attitude in one trial: every model of it diverges."""
    ads_q = data.ads_q.copy()
    ads_q[trial, epoch] = np.nan
    return ScenarioData(**{**vars(data), "ads_q": ads_q})


def _assert_close_outputs(out: MethodOutput, ref: MethodOutput, log: str, w_atol: float) -> None:
    np.testing.assert_array_equal(out.diverged, ref.diverged)
    np.testing.assert_array_equal(np.isnan(out.est), np.isnan(ref.est))
    fin = np.isfinite(ref.est).all(axis=-1)
    for sl in (slice(4, 7), slice(7, 16)):
        scale = np.abs(ref.est[fin][:, sl]).max()
        assert np.abs(out.est[fin][:, sl] - ref.est[fin][:, sl]).max() <= 1e-10 * scale
    assert _angle(out.est[fin][:, 0:4], ref.est[fin][:, 0:4]).max() < 1e-14
    np.testing.assert_allclose(out.logs[log], ref.logs[log], rtol=0, atol=w_atol)
    assert out.cov is not None and ref.cov is not None
    np.testing.assert_array_equal(np.isnan(out.cov), np.isnan(ref.cov))
    assert np.nanmax(np.abs(out.cov - ref.cov) / np.nanmax(np.abs(ref.cov))) < 1e-9


def test_run_mmae_is_its_numpy_driver() -> None:
    cfg = cfg_with("scenario.duration_s=300")
    data = _break_trial(simulate(cfg, 4, 3), 2, 120)
    out = run_mmae(cfg, data)
    with np.errstate(invalid="ignore"):  # no live model left in trial 2: NaN weights
        ref = run_mmae_reference(cfg, data)
    np.testing.assert_array_equal(out.diverged, [False, False, True])
    # the model probabilities: rounding only (the filters are the kernel's, bit for bit)
    _assert_close_outputs(out, ref, "weights", 1e-12)


@pytest.mark.parametrize(
    "prm",
    [ImmConfig(), ImmConfig(p_stay=0.9, switching="neighbours", mix_every=3)],
    ids=["uniform-every-epoch", "neighbours-every-3"],
)
def test_imm_filter_is_its_numpy_driver(prm: ImmConfig) -> None:
    """Equal to rounding; the model probabilities amplify it (the module doc of imm: one unit in
    the last place of the mixed covariances moves them by ~1e-10), hence their 1e-9."""
    cfg = cfg_with("scenario.duration_s=200")
    data = _break_trial(simulate(cfg, 5, 3), 1, 90)
    out, ref = imm_filter(cfg, data, prm), imm_filter_reference(cfg, data, prm)
    np.testing.assert_array_equal(out.diverged, [False, True, False])
    dead = np.isnan(out.est[1]).all(axis=-1)
    assert np.isfinite(out.est[1, :90]).all() and dead[-1] and np.all(dead[np.argmax(dead) :])
    _assert_close_outputs(out, ref, "probabilities", 1e-9)
    assert out.kappa is not None and ref.kappa is not None
    np.testing.assert_allclose(out.kappa, ref.kappa, rtol=1e-8)
