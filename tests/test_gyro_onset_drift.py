"""The redundant-gyro onset/drift option, ``qkf/RedundantGyroCalibration-v1`` and the gyro
hindsight yardstick (docs/redundant_gyros.md, "Onset and drift", "Hindsight")."""

from __future__ import annotations

import hashlib

import gymnasium as gym
import numpy as np
import pytest
from scipy import stats

import envs  # noqa: F401  (registers the ids)
from envs.redundant_gyros import GYRO_ENV_ID_V1, RedundantGyroCalibrationEnv
from qkf.core.config import ConfigError
from qkf.core.units import DEG
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.config import OnsetDrift
from qkf.redundant_gyros.pipeline import simulate_run
from qkf.redundant_gyros.scenario import draw_onset, epochs, onset_generator
from qkf.redundant_gyros.ukf import CalibrationUKF

PRESET = "five_gyros_onset_drift"


def test_onset_is_drawn_in_its_range_and_reproducible() -> None:
    cfg = load_config(PRESET)
    lo, hi = cfg.scenario.onset.onset_s  # type: ignore[union-attr]
    a = [simulate_run(cfg, seed=s).onset_s for s in range(40)]
    b = [simulate_run(cfg, seed=s).onset_s for s in range(40)]
    onsets = np.array([float(x[0]) for x in a if x is not None])
    assert onsets.size == 40 and np.all((onsets >= lo) & (onsets <= hi))
    assert np.array_equal(onsets, np.array([float(x[0]) for x in b if x is not None]))
    assert np.unique(onsets).size == 40  # drawn, not fixed
    # the truth steps at the onset: constant before, different after
    d = simulate_run(cfg, seed=3)
    coeffs = d.trial_coeffs(0)
    assert coeffs is not None and d.onset_s is not None
    k = int(np.searchsorted(d.t, d.onset_s[0]))
    s_gyro = 3
    assert np.all(coeffs[:k, s_gyro] == coeffs[0, s_gyro])
    assert not np.array_equal(coeffs[k, s_gyro], coeffs[0, s_gyro])


def test_drift_variance_grows_as_sigma_squared_t() -> None:
    spec = OnsetDrift(
        gyro="S",
        onset_s=(20.0, 20.0),
        drift={  # type: ignore[arg-type]
            "bias_deg_s_per_sqrt_s": 1e-3,
            "scale_per_sqrt_s": 2e-4,
            "delta_u_deg_per_sqrt_s": 0.1,
            "delta_v_deg_per_sqrt_s": 0.05,
        },
    )
    t = epochs(100.0, 0.5)
    sigma = np.array([1e-3, 2e-4, 0.1 * DEG, 0.05 * DEG])
    n = 2000
    walks = np.stack([draw_onset(spec, t, onset_generator(11, k)).walk for k in range(n)])
    k0 = int(np.searchsorted(t, 20.0))
    assert np.all(walks[:, : k0 + 1] == 0.0)  # starts at the onset, from 0
    level = 1e-4  # each of the 8 checks; a false failure about once in 1000 runs
    for k in (k0 + 20, t.size - 1):  # 10 s and 79.5 s after the onset
        var = sigma**2 * (t[k] - t[k0])
        ss = np.sum(walks[:, k] ** 2, axis=0) / var  # ~ χ²_n (mean 0 known)
        lo, hi = stats.chi2.ppf([level / 2, 1 - level / 2], n)
        assert np.all((ss > lo) & (ss < hi)), ss / n


def test_default_configs_are_unchanged() -> None:
    """A v0 episode and a simulation of a preset without the option: the values computed
    before the option existed."""
    env = RedundantGyroCalibrationEnv(overrides=["scenario.duration_s=90"])
    obs, info = env.reset(seed=123)
    assert "onset_s" not in info
    out, rewards = [obs], []
    for a in [0, 5, 10, 3, 7, 1, 9, 2, 8, 4]:
        o, r, term, trunc, info = env.step(a)
        out.append(o)
        rewards.append(r)
        if term or trunc:
            break
    assert len(out) == 4
    # The UKF runs through filterpy/scipy, whose BLAS/LAPACK kernels differ by CPU, and its
    # inputs through sin: the values are one machine's, with tolerances ~10x what such
    # differences moved them (measured on one machine with OpenBLAS's five x86-64 kernel
    # families, and with every body rate moved by one ulp at random). The reward sum is a
    # difference of nearly equal log-likelihoods: up to 9.2e-9 relative (an AMD EPYC gave
    # -0.0003001788697474865, 7.5e-9), hence rtol 1e-7.
    np.testing.assert_allclose(float(np.sum(rewards)), -0.0003001788675078558, rtol=1e-7)
    # float32 observations: one element moved by a float32 ulp on 4 of the 5 kernels; 1e-6 is a
    # few float32 ulps (6e-8 relative each) of the sum.
    np.testing.assert_allclose(
        float(np.sum(np.abs(np.concatenate(out)))), 54.055721282958984, rtol=1e-6
    )
    # the estimate's errors moved by up to 8.7e-12 relative: rtol 1e-9 (~100x)
    np.testing.assert_allclose(
        info["errors"],
        [
            7.154316086871448e-05,
            -6.426940088767965e-05,
            -0.002645736968502734,
            0.002096764811515362,
        ],
        rtol=1e-9,
    )
    d = simulate_run(load_config("five_gyros_s_bias"), seed=7)
    assert d.onset_s is None and d.coeffs is not None and d.coeffs.ndim == 3
    # The readings go through sin and einsum, whose last bits depend on the CPU (numpy's SIMD
    # kernels, libm): per gyro the mean and RMS over the run and the readings at the fault's
    # epoch (t = 60 s), to 1e-9 relative; atol 1e-12 deg/s is far below the noise (1e-3 deg/s)
    # and far above rounding (readings up to 5.2 deg/s, 1e-15 per ulp).
    assert d.meas.shape == (1, 6000, 5)
    m = d.meas[0]
    np.testing.assert_allclose(
        [m.mean(axis=0), np.sqrt(np.mean(m**2, axis=0)), m[600]],
        [
            [0.4890052110126635, -0.31465121525945994, 0.1790947670358028,
             0.13282799101398363, 0.25018216351501243],
            [2.172825142512663, 2.1415780922779475, 2.1236628464383136,
             2.1100162498413972, 2.1225994567660535],
            [0.4887247584305857, 0.5725003640254489, 0.1891359558978784,
             0.6402190689472639, 0.7605990425222094],
        ],
        rtol=1e-9,
        atol=1e-12,
    )  # fmt: skip
    # the true coefficients are the config's values plus the fault's step (IEEE additions,
    # correctly rounded on every CPU): bit for bit
    assert hashlib.sha256(d.coeffs.tobytes()).hexdigest().startswith("9ed8b73ff61c89ac")


def test_the_noise_is_the_same_with_the_option_on_or_off() -> None:
    on = load_config(PRESET, ["scenario.duration_s=60"])
    off = load_config(PRESET, ["scenario.duration_s=60", "scenario.onset.onset_s=[1e9,1e9]"])
    a, b = simulate_run(on, seed=5), simulate_run(off, seed=5)
    assert a.coeffs is not None and b.coeffs is not None
    # the same noise stream: the readings agree up to the onset (past the end for ``off``)
    k = int(np.searchsorted(a.t, a.onset_s[0])) if a.onset_s is not None else a.t.size
    assert np.array_equal(a.meas[0, :k], b.meas[0, :k])


def test_onset_config_is_checked() -> None:
    with pytest.raises(ConfigError, match="onset_s"):
        load_config(PRESET, ["scenario.onset.onset_s=[300,100]"])
    with pytest.raises(ConfigError, match="unknown gyro"):
        load_config(PRESET, ["scenario.onset.gyro=Q"])


def test_env_v1_observation_has_no_clock_and_is_finite() -> None:
    env = gym.make(GYRO_ENV_ID_V1, overrides=["scenario.duration_s=200"])
    u = env.unwrapped
    assert isinstance(u, RedundantGyroCalibrationEnv)
    assert u.observation == "v1" and env.observation_space.shape == (8,)
    assert u.cfg.name == "five-gyros-onset-drift"
    obs, info = env.reset(seed=5_000_000)
    assert obs.shape == (8,) and "onset_s" in info
    v0 = RedundantGyroCalibrationEnv(PRESET, overrides=["scenario.duration_s=200"])
    o0, _ = v0.reset(seed=5_000_000)
    steps = 0
    done = False
    while not done:
        obs, r, term, trunc, info = env.step(7)
        o0, r0, *_ = v0.step(7)
        assert np.all(np.isfinite(obs)) and env.observation_space.contains(obs)
        # v1 is v0 less the elapsed fraction (entry 6), the same episode
        assert np.array_equal(obs, np.delete(o0, 6)) and r == r0
        steps += 1
        done = term or trunc
    assert steps == u.episode_steps and not info["diverged"]


def test_compiled_ukf_matches_filterpy() -> None:
    cfg = load_config(PRESET, ["scenario.duration_s=60"])
    ep = hs.episode(cfg, 5_000_001, settled_s=10.0)
    kap = ep.kappas[np.repeat(np.arange(ep.n_periods) % ep.kappas.size, ep.period)]
    kap = kap[: ep.n_epochs]
    est = hs.CompiledUKF(ep).estimates(kap)
    ref = CalibrationUKF(ep.setup, float(ep.inputs.dt[0]))
    i = ep.inputs
    for k in range(ep.n_epochs):
        assert ref.step(float(i.z[k]), i.rate[k], float(i.dt[k]), float(kap[k])).ok
        assert np.all(np.abs(est[k] - ref.x) <= 1e-9 * ep.setup.p0_sd)


def test_hindsight_episode_is_the_environment_episode() -> None:
    cfg = load_config(PRESET, ["scenario.duration_s=60"])
    ep = hs.episode(cfg, 5_000_002, settled_s=10.0)
    env = RedundantGyroCalibrationEnv(cfg, observation="v1")
    _, info = env.reset(seed=5_000_002)
    assert info["onset_s"] == ep.inputs.onset_s
    e = env.episodes
    assert np.array_equal(e.z[0], ep.inputs.z) and np.array_equal(e.truth[0], ep.inputs.truth)


@pytest.mark.parametrize("seed", [5_000_003, 5_000_004])
def test_hindsight_is_never_worse_than_a_constant(seed: int) -> None:
    cfg = load_config(PRESET, ["scenario.duration_s=160", "scenario.onset.onset_s=[60,100]"])
    ep = hs.episode(cfg, seed, settled_s=20.0)
    res = hs.search(ep, blocks=(4, 1))
    assert res.score <= np.min(res.constant_scores)
    assert list(res.stage_scores) == sorted(res.stage_scores, reverse=True)
    # the schedule's own score, recomputed from scratch
    ukf = hs.CompiledUKF(ep)
    x, p = ukf.prior()
    kap = res.kappa(ep.kappas, ep.period, ep.n_epochs)
    assert ukf.score(ukf.run(x, p, kap, 0, ep.n_epochs)) == pytest.approx(res.score, rel=1e-12)
    two = hs.two_level_scores(ep)
    assert np.allclose(np.diag(two), res.constant_scores, rtol=1e-12)
