"""The redundant-gyro environments on the compiled, batched UKF (``GyroEpisodes``): filterpy's
filter over whole episodes with κ changing, the episode sampler against the simulation, the
single environment against the Gymnasium and SB3 batched ones, the κ = 1 copy only where it is
read, the batched action map and the vector environment's spaces and seeding."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import envs  # registers the ids
from envs.common.actions import ActionMap
from envs.redundant_gyros import (
    GYRO_ENV_ID,
    GYRO_ENV_ID_V1,
    GYRO_ENV_ID_V2,
    GYRO_ENV_ID_V3,
    GYRO_ENV_ID_V4,
)
from envs.redundant_gyros.episodes import GyroEpisodes
from envs.redundant_gyros.observations import GYRO_OBSERVATIONS, PART_SIZES
from envs.redundant_gyros.sb3 import BatchedGyroSB3Env
from envs.redundant_gyros.vector import BatchedGyroCalibrationEnv
from qkf.redundant_gyros import load_config
from qkf.redundant_gyros.episodes import EpisodeSampler
from qkf.redundant_gyros.geometry import build_unit
from qkf.redundant_gyros.pipeline import fault_target, setup_for
from qkf.redundant_gyros.scenario import epochs, simulate
from qkf.redundant_gyros.ukf import (
    DISPLAY_SCALE,
    CalibrationUKF,
    UkfSetup,
    log_likelihood,
    measurement,
    measurement_variance,
    triad_rate,
)
from qkf.redundant_gyros.ukf_compiled import SUMS

# 1200 calibrated epochs from t = 0, an onset drawn in [30, 60] s: inside the episode
ONSET = ["scenario.duration_s=120", "scenario.onset.onset_s=[30,60]"]
SCHEDULE = [0, 10, 3, 7, 5, 2, 8, 1, 9, 4, 6]  # visits every κ of the default action set


@pytest.fixture(autouse=True)
def _no_out_of_date_warning() -> Iterator[None]:
    # v0 and v1 are kept for their policies; Gymnasium warns that v2 supersedes them
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "(?s).*out of date.*", DeprecationWarning)
        yield


def _seed_draw(seed: int) -> int:
    """The simulation seed a Gymnasium ``reset(seed=seed)`` draws for its episode."""
    return int(np.random.default_rng(seed).integers(2**63 - 1))


# -- 1. the compiled environment against filterpy --------------------------------------------


def _post_fit(setup: UkfSetup, ref: CalibrationUKF, x_before: np.ndarray, z: float,
              rate: np.ndarray) -> tuple[float, float]:  # fmt: skip
    """``((z − h(x̂))² / R₀, H P Hᵀ / R₀)`` after one filterpy step, ``R₀`` at the state before
    it and ``H`` by central differences (exact: ``h`` is linear in each coordinate)."""
    h_row = np.empty(4)
    for j in range(4):
        step = np.zeros(4)
        step[j] = 1e-3 * setup.p0_sd[j]
        up, down = measurement(ref.x + step, rate, setup), measurement(ref.x - step, rate, setup)
        h_row[j] = float(up[0] - down[0]) / (2 * step[j])
    r0 = measurement_variance(setup, x_before)
    resid = z - float(measurement(ref.x, rate, setup)[0])
    return resid**2 / r0, float(h_row @ ref.P @ h_row) / r0


@pytest.mark.parametrize(
    ("env_id", "overrides", "seed"),
    [
        (GYRO_ENV_ID_V1, ONSET, 11),  # calibrated from t = 0, an onset inside
        (GYRO_ENV_ID, ["scenario.duration_s=90"], 4),  # five_gyros_s_bias: from the fault on
        (GYRO_ENV_ID_V3, ["scenario.duration_s=120"], 12),  # noise levels; the lag-1 entry
        (GYRO_ENV_ID_V4, ["scenario.duration_s=120"], 13),  # and the VB noise scale
    ],
)
def test_compiled_env_follows_filterpy_with_kappa_changing(
    env_id: str, overrides: list[str], seed: int
) -> None:
    env = gym.make(env_id, overrides=overrides, reward="likelihood")
    u = env.unwrapped
    assert isinstance(u, envs.RedundantGyroCalibrationEnv)
    env.reset(seed=seed)
    ep = EpisodeSampler(u.cfg).draw(_seed_draw(seed))
    episodes = u.episodes
    np.testing.assert_array_equal(episodes.z[0], ep.z)
    np.testing.assert_array_equal(episodes.rate[0], ep.rate)
    np.testing.assert_array_equal(episodes.truth[0], ep.truth)

    setup = u.setup
    p0 = setup.p0_sd
    n_epochs = ep.z.size
    kappas = u.actions.kappas
    parts = GYRO_OBSERVATIONS[u.observation].parts
    ref = CalibrationUKF(setup, float(ep.dt[0]))
    nominal = CalibrationUKF(setup, float(ep.dt[0]))
    k = 0
    visited = set()
    alpha = beta = 0.5 * u.period  # the R scale's prior: one period at the assumed noise
    for n in range(u.episode_steps):
        a = SCHEDULE[n % len(SCHEDULE)]
        kappa = float(kappas[a])
        visited.add(a)
        nominal.load(ref.x.copy(), ref.P.copy())  # the κ = 1 copy from the period's start
        k1 = min(k + u.period, n_epochs)
        ll_agent = ll_nominal = nis = lag1 = 0.0
        r_prev = None
        theta_before, resid_sum = beta / alpha, 0.0
        for j in range(k, k1):
            z, rate, dt = float(ep.z[j]), ep.rate[j], float(ep.dt[j])
            x_before = ref.x.copy()
            r = ref.step(z, rate, dt, kappa)
            resid, hph = _post_fit(setup, ref, x_before, z, rate)
            resid_sum += resid + theta_before * hph
            rn = nominal.step(z, rate, dt, 1.0)
            assert r.ok and rn.ok
            ll_agent += float(log_likelihood(np.array(r.innovation), np.array(r.variance)))
            ll_nominal += float(log_likelihood(np.array(rn.innovation), np.array(rn.variance)))
            nis += r.innovation**2 / r.variance
            r_norm = r.innovation / np.sqrt(r.variance)
            if r_prev is not None:
                lag1 += r_norm * r_prev
            r_prev = r_norm
        alpha, beta = alpha + 0.5 * (k1 - k), beta + 0.5 * resid_sum
        obs, reward, term, trunc, info = env.step(a)
        assert not term and trunc == (k1 == n_epochs)
        assert info["kappa"] == kappa

        # the state and covariance after the period, to 1e-9 σ₀ and 1e-9 relative
        x_env, p_env = episodes.x[0], episodes.p[0]
        assert np.all(np.abs(x_env - ref.x) <= 1e-9 * p0), (n, x_env - ref.x)
        np.testing.assert_allclose(np.diag(p_env), np.diag(ref.P), rtol=1e-9, atol=0)
        err = (ref.x - ep.truth[k1 - 1]) / DISPLAY_SCALE
        assert np.all(np.abs(info["errors"] - err) <= 1e-9 * p0 / DISPLAY_SCALE), n

        # the likelihood reward: (ℓ_agent − ℓ_nominal) / (steps Δt), a difference of near sums
        steps = k1 - k
        span = steps * float(ep.dt[k])
        expected = (ll_agent - ll_nominal) / span
        tol = 1e-9 * (abs(ll_agent) + abs(ll_nominal)) / span + 1e-12
        assert abs(float(reward) - expected) <= tol, (n, reward, expected)

        # the observation, entry by entry (float32)
        gain = (ll_agent - ll_nominal) / steps
        want = {
            "sd": np.log10(np.sqrt(np.diag(ref.P)) / p0),
            "nis": np.array([nis / steps]),
            "lag1": np.array([lag1 / max(steps - 1, 1)]),
            "gain": np.array([gain]),
            "time": np.array([k1 / n_epochs]),
            "rate": np.array([np.linalg.norm(ep.rate[k1 - 1])]),
            "kappa": np.array([a / (kappas.size - 1)]),
            "rscale": np.array([np.log10(beta / alpha)]),
        }
        expected_obs = np.concatenate([want[p] for p in parts])
        gain_tol = 1e-9 * (abs(ll_agent) + abs(ll_nominal)) / steps + 1e-6 * abs(gain)
        tols = {"gain": gain_tol, "lag1": 1e-9}  # lag1: a sum of ±1 products, near 0
        atol = np.concatenate([np.full(want[p].size, tols.get(p, 0.0)) for p in parts])
        assert obs.dtype == np.float32 and obs.shape == expected_obs.shape
        assert np.all(np.abs(obs - expected_obs) <= atol + 1e-6 * np.abs(expected_obs)), (
            n,
            obs,
            expected_obs,
        )
        k = k1
    assert k == n_epochs and trunc
    assert len(visited) >= min(len(SCHEDULE), u.episode_steps)


# -- 2. the episode sampler against the simulation -------------------------------------------


@pytest.mark.parametrize(
    ("preset", "overrides"),
    [
        ("five_gyros_onset_drift", []),
        # the onset on a gyro of the triad (its readings change ω̂_H, not the calibrated truth)
        ("five_gyros_onset_drift", ["scenario.duration_s=200", "scenario.onset.gyro=X"]),
        # a walk from the start, calibrated from 30 s on
        (
            "five_gyros_onset_drift",
            [
                "scenario.duration_s=200",
                "scenario.onset.drift_from=start",
                "calibration.start_s=30",
            ],
        ),
        ("five_gyros_s_bias", []),
        ("five_gyros_y_misalignment", []),
    ],
)
def test_sampler_draws_trial_zero_of_the_simulation(preset: str, overrides: list[str]) -> None:
    cfg = load_config(preset, overrides)
    sc = cfg.scenario
    sampler = EpisodeSampler(cfg)
    unit = build_unit(cfg)
    t = epochs(sc.duration_s, sc.dt_s)
    target = fault_target(cfg, unit, t)
    setup = setup_for(cfg, unit, target)
    np.testing.assert_array_equal(sampler.t, t)
    assert sampler.target == target and sampler.setup.gyro == setup.gyro
    start, gyro = target.start, setup.gyro
    assert sampler.n_epochs == t.size - start
    # the steps before each calibrated epoch, as calibrate() takes them
    dt = np.diff(t[start - 1 :]) if start > 0 else np.concatenate([[t[1] - t[0]], np.diff(t)])
    seen = []
    for seed in [0, 7, _seed_draw(3)]:
        ep = sampler.draw(seed)
        data = simulate(unit, sc.body_rate, sc.faults, t, seed, [0], sc.onset)
        coeffs = data.trial_coeffs(0)
        assert coeffs is not None
        np.testing.assert_array_equal(ep.truth, coeffs[start:, gyro])
        if sc.onset is None:
            assert ep.onset_s is None and data.onset_s is None
        else:
            assert data.onset_s is not None and ep.onset_s == float(data.onset_s[0])
        meas = data.meas[0]
        np.testing.assert_allclose(ep.z, meas[start:, gyro], rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            ep.rate, triad_rate(unit, setup, meas[start:]), rtol=0, atol=1e-12
        )
        np.testing.assert_array_equal(ep.dt, dt)
        assert ep.t0_s == t[start]
        seen.append(ep.z)
    assert not np.array_equal(seen[0], seen[1])  # the seed matters


# -- 3. single against batched ---------------------------------------------------------------

SHORT = {
    GYRO_ENV_ID: ["scenario.duration_s=180"],  # five_gyros_s_bias: 1200 epochs from 60 s on
    GYRO_ENV_ID_V1: ONSET,
    GYRO_ENV_ID_V2: ONSET,
    GYRO_ENV_ID_V3: ["scenario.duration_s=120"],  # gyro_noise_levels from t = 0
    GYRO_ENV_ID_V4: ["scenario.duration_s=120"],
}


def _short(env_id: str, **kwargs: Any) -> dict[str, Any]:
    """Keywords of a short episode of ``env_id``: 1200 epochs, 4 decision periods of 30 s."""
    return {"overrides": SHORT[env_id], "period_s": 30.0, **kwargs}


def _single_rows(env_id: str, n: int) -> list[gym.Env[np.ndarray, Any]]:
    return [gym.make(env_id, **_short(env_id)) for _ in range(n)]


@pytest.mark.parametrize("env_id", [GYRO_ENV_ID_V1, GYRO_ENV_ID_V2, GYRO_ENV_ID_V4])
def test_single_and_gymnasium_vector_env_agree_bit_for_bit(env_id: str) -> None:
    n, seed = 3, 20
    vec = gym.make_vec(env_id, num_envs=n, **_short(env_id))
    assert isinstance(vec, BatchedGyroCalibrationEnv)
    length = vec.episode_steps
    singles = _single_rows(env_id, n)
    obs_v, info_v = vec.reset(seed=seed)
    firsts = [env.reset(seed=seed + i) for i, env in enumerate(singles)]
    np.testing.assert_array_equal(obs_v, np.stack([o for o, _ in firsts]))
    np.testing.assert_array_equal(info_v["onset_s"], [i["onset_s"] for _, i in firsts])

    n_actions = vec.episodes.actions.kappas.size
    actions = np.random.default_rng(1).integers(0, n_actions, (3 * length, n))
    ended = np.zeros(n, dtype=bool)
    ends = 0
    for act in actions:
        obs_v, rew_v, term_v, trunc_v, info_v = vec.step(act)
        for i, env in enumerate(singles):
            if ended[i]:  # next-step autoreset: this step starts the next episode
                o, _ = env.reset()
                r, te, tr = 0.0, False, False
            else:
                o, r_, te, tr, _ = env.step(int(act[i]))
                r = float(r_)
            assert np.array_equal(obs_v[i], o), (i, obs_v[i], o)
            assert rew_v[i] == r and term_v[i] == te and trunc_v[i] == tr
            ended[i] = te or tr
            ends += int(ended[i])
        u0 = singles[0].unwrapped
        assert isinstance(u0, envs.RedundantGyroCalibrationEnv)
        assert info_v["onset_s"][0] == u0.episodes.onset(0)
    assert ends >= 2 * n  # every row went through two episode ends (and restarts)


@pytest.mark.parametrize("observation", ["v1", "v2", "v4"])
def test_single_and_sb3_vec_env_agree_bit_for_bit(observation: str) -> None:
    n, seed = 3, 33
    env_id = {"v1": GYRO_ENV_ID_V1, "v2": GYRO_ENV_ID_V2, "v4": GYRO_ENV_ID_V4}[observation]
    vec = BatchedGyroSB3Env(n, observation=observation, **_short(env_id))
    length = vec.episodes.episode_steps
    singles = _single_rows(env_id, n)
    vec.seed(seed)
    first = vec.reset()
    assert isinstance(first, np.ndarray)
    np.testing.assert_array_equal(
        first, np.stack([env.reset(seed=seed + i)[0] for i, env in enumerate(singles)])
    )
    actions = np.random.default_rng(2).integers(0, 11, (2 * length + 2, n))
    dones_seen = 0
    for act in actions:
        obs_v, rew_v, done_v, infos = vec.step(act)
        assert isinstance(obs_v, np.ndarray)
        for i, env in enumerate(singles):
            o, r, te, tr, _ = env.step(int(act[i]))
            assert rew_v[i] == np.float32(r)
            assert done_v[i] == (te or tr)
            if te or tr:  # same-step autoreset: the final observation in the info
                dones_seen += 1
                assert np.array_equal(infos[i]["terminal_observation"], o)
                assert infos[i]["TimeLimit.truncated"] == (tr and not te)
                o, _ = env.reset()
            else:
                assert "terminal_observation" not in infos[i]
            assert np.array_equal(obs_v[i], o), (i, obs_v[i], o)
    assert dones_seen == 2 * n


@pytest.mark.parametrize("env_id", [GYRO_ENV_ID_V3, GYRO_ENV_ID_V4])
def test_an_episode_after_a_reset_is_the_episode_of_a_fresh_env(env_id: str) -> None:
    """Nothing of an earlier episode carries over (the v4 noise scale's posterior included):
    after a whole episode and a reset, the steps are those of a new environment reset with the
    same seed."""
    used, fresh = gym.make(env_id, **_short(env_id)), gym.make(env_id, **_short(env_id))
    used.reset(seed=5)
    done = False
    while not done:
        _, _, te, tr, _ = used.step(9)
        done = te or tr
    for env in (used, fresh):
        env.reset(seed=6)
    for a in (2, 7, 4):
        np.testing.assert_array_equal(used.step(a)[0], fresh.step(a)[0])


# -- 4. the κ = 1 copy only where it is read --------------------------------------------------


def test_nominal_copy_runs_only_where_read() -> None:
    def needs(observation: str, reward: str | None = None) -> bool:
        eps = GyroEpisodes(2, "five_gyros_onset_drift", observation=observation, reward=reward)
        return eps.needs_nominal

    assert not needs("v2", "oracle") and not needs("v2")  # v2's own reward is oracle
    assert needs("v2", "likelihood") and needs("v1", "oracle") and needs("v1")

    nominal_sum = SUMS.index("loglik_nominal")
    parts_v1, parts_v2 = GYRO_OBSERVATIONS["v1"].parts, GYRO_OBSERVATIONS["v2"].parts
    assert tuple(p for p in parts_v1 if p != "gain") == parts_v2
    gain = sum(PART_SIZES[p] for p in parts_v1[: parts_v1.index("gain")])  # its column
    n = 3

    def make(env_id: str, reward: str) -> BatchedGyroCalibrationEnv:
        vec = gym.make_vec(env_id, num_envs=n, **_short(env_id, reward=reward))
        assert isinstance(vec, BatchedGyroCalibrationEnv)
        return vec

    v1, v2 = make(GYRO_ENV_ID_V1, "oracle"), make(GYRO_ENV_ID_V2, "oracle")
    v1_lik, v2_lik = make(GYRO_ENV_ID_V1, "likelihood"), make(GYRO_ENV_ID_V2, "likelihood")
    assert v1.episodes.needs_nominal and not v2.episodes.needs_nominal
    outs = [e.reset(seed=5)[0] for e in (v1, v2, v1_lik, v2_lik)]
    np.testing.assert_array_equal(np.delete(outs[0], gain, axis=1), outs[1])
    rng = np.random.default_rng(4)
    gains = []
    restarting = np.zeros(n, dtype=bool)
    for _ in range(v1.episode_steps + 2):  # through the episodes' end and the restart
        act = rng.integers(0, 11, n)
        o1, r1, te1, tr1, _ = v1.step(act)
        o2, r2, te2, tr2, _ = v2.step(act)
        _, r1l, _, _, _ = v1_lik.step(act)
        _, r2l, _, _, _ = v2_lik.step(act)
        np.testing.assert_array_equal(np.delete(o1, gain, axis=1), o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(r2l, r1l)  # the copy runs for the reward alone, too
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)
        gains.append(o1[:, gain])
        # v2 with oracle: no copy ran (its sum stays 0); v1 and v2 with likelihood: it did
        np.testing.assert_array_equal(v2.episodes.sums[:, nominal_sum], 0.0)
        for e in (v1, v2_lik):
            assert np.all(e.episodes.sums[~restarting, nominal_sum] != 0.0)
        restarting = te1 | tr1
    assert np.any(np.array(gains) != 0.0)  # the entry v2 leaves out carries something


# -- 5. the batched action map ---------------------------------------------------------------


def test_action_map_many() -> None:
    kappas = np.asarray(load_config("five_gyros_onset_drift").environment.actions.values())
    big = kappas.size
    amap = ActionMap(kappas, "discrete")
    a = np.array([0, big - 1, 3, 3, 7])
    k, pos = amap.many(a)
    np.testing.assert_array_equal(k, kappas[a])
    np.testing.assert_array_equal(pos, a / (big - 1))
    assert k.dtype == np.float64 and pos.dtype == np.float64
    # the one-by-one path agrees (a float array of whole numbers, an (N, 1) array)
    for other in (a.astype(float), a[:, None]):
        k2, pos2 = amap.many(other)
        np.testing.assert_array_equal(k2, k)
        np.testing.assert_array_equal(pos2, pos)
    for bad in (np.array([0, big]), np.array([-1, 2]), np.array([2, big + 5, -3])):
        with pytest.raises(ValueError, match="outside"):
            amap.many(bad)
    with pytest.raises(ValueError):
        amap.many(np.array([0.5, 1.0]))

    cont = ActionMap(kappas, "continuous")
    acts = np.array([[-1.0], [-0.3], [0.0], [0.25], [1.0]], dtype=np.float32)
    k, pos = cont.many(acts)
    single = [cont(x) for x in acts]
    np.testing.assert_array_equal(k, [s[0] for s in single])
    np.testing.assert_array_equal(pos, [s[1] for s in single])
    assert k[0] == pytest.approx(kappas[0]) and k[-1] == pytest.approx(kappas[-1])
    with pytest.raises(ValueError):
        cont.many(np.array([[0.0], [1.5]]))


# -- 6. the vector environment's spaces and seeding ------------------------------------------


@pytest.mark.parametrize("env_id", [GYRO_ENV_ID, GYRO_ENV_ID_V1, GYRO_ENV_ID_V2])
def test_vector_env_spaces_and_seeding(env_id: str) -> None:
    n = 4
    vec = gym.make_vec(env_id, num_envs=n, **_short(env_id))
    assert isinstance(vec, BatchedGyroCalibrationEnv)
    single = gym.make(env_id, **_short(env_id))
    assert vec.single_observation_space == single.observation_space
    assert vec.single_action_space == single.action_space
    size = vec.episodes.observation.size
    assert single.observation_space.shape == (size,)
    assert vec.observation_space.shape == (n, size)

    def run(seed: int) -> list[tuple[np.ndarray, ...]]:
        vec.action_space.seed(seed)
        obs, _ = vec.reset(seed=seed)
        out: list[tuple[np.ndarray, ...]] = [(obs,)]
        for _ in range(vec.episode_steps + 2):
            obs, rew, term, trunc, _ = vec.step(vec.action_space.sample())
            out.append((obs, rew, term, trunc))
        return out

    first = run(8)
    for rec in first:
        obs = rec[0]
        assert vec.observation_space.contains(obs)
        assert obs.dtype == np.float32 and obs.shape == (n, size)
        for row in obs:
            assert vec.single_observation_space.contains(row)
        if len(rec) > 1:
            assert rec[1].shape == (n,) and np.all(np.isfinite(rec[1]))
            assert rec[2].dtype == bool and rec[3].dtype == bool
    assert any(np.all(rec[3]) for rec in first[1:])  # the episodes ended on the way
    again = run(8)
    for a, b in zip(first, again, strict=True):
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x, y)
    other = run(9)
    assert not np.array_equal(first[1][0], other[1][0])


@pytest.mark.parametrize("env_id", [GYRO_ENV_ID, GYRO_ENV_ID_V1, GYRO_ENV_ID_V2])
def test_vector_autoreset_step_warns_nothing(env_id: str) -> None:
    """The step after an episode's end restarts it (next-step autoreset): nothing of the
    finished episode is computed there, so nothing may warn (RuntimeWarnings of envs.* are
    errors in this suite)."""
    vec = gym.make_vec(env_id, num_envs=2, **_short(env_id))
    assert isinstance(vec, BatchedGyroCalibrationEnv)
    vec.reset(seed=1)
    act = np.array([3, 8])
    for _ in range(vec.episode_steps):
        _, _, _, trunc, _ = vec.step(act)
    assert np.all(trunc)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, rew, term, trunc, _ = vec.step(act)  # the autoreset step
    warned = [
        f"{w.filename}:{w.lineno}: {w.message}"
        for w in caught
        if issubclass(w.category, RuntimeWarning)
    ]
    assert warned == []
    np.testing.assert_array_equal(rew, 0.0)
    assert not np.any(term) and not np.any(trunc)
