"""qkf/TransferAlignment-v4: the filter's moves (kernel factors, resets, assumed ADS σ), the
controls that map actions to them, residual bases, experts and the observation's slow
evidence (docs/environment.md, "Controls")."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from envs.transfer_alignment.controls import ControlMap, parse_controls
from envs.transfer_alignment.episodes import EpisodeDriver
from envs.transfer_alignment.observations import SLOW_WINDOWS_S
from qkf.transfer_alignment.config import load_scenario
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.judging import estimate_scores
from qkf.transfer_alignment.methods import resolve_method
from qkf.transfer_alignment.methods.moves_schedule import MoveSchedule, run_moves
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.moves import Moves, apply_moves
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import simulate

SHORT = ["scenario.duration_s=600"]


def _run(params: FilterParams, data, q_scale=None, kappa=1.0) -> np.ndarray:  # type: ignore[no-untyped-def]
    kf = TransferAlignmentKF(params, data.n_trials)
    kf.initialize(data.ads_q[:, 0])
    if q_scale is not None:
        kf.q_scale[:] = q_scale
    return kf.step_data(data, 0, data.n_epochs, kappa).est


@pytest.mark.parametrize("scenario", ["thermal_snap", "attitude_only"])
def test_bias_factor_is_a_scaled_rate_random_walk(scenario: str) -> None:
    """q_bias = s in the kernel is the filter whose σ_u is √s σ_u (σ_u enters Q only)."""
    cfg = load_scenario(scenario, SHORT)
    data = simulate(cfg, 3, [0, 1])
    params = FilterParams.from_config(cfg)
    s = 7.0
    scaled = dataclasses.replace(params, sigma_u=params.sigma_u * np.sqrt(s))
    got = _run(params, data, q_scale=np.array([1.0, s]))
    want = _run(scaled, data)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-15)
    # and the factor matters: the nominal filter differs
    assert np.max(np.abs(_run(params, data) - want)) > 1e-9


def test_attitude_factor_is_a_scaled_arw_in_q_without_rate_matching() -> None:
    """Attitude-only matching: σ_v enters Q only, so q_att = s is the filter with √s σ_v."""
    cfg = load_scenario("attitude_only", SHORT)
    data = simulate(cfg, 4, [0, 1])
    params = FilterParams.from_config(cfg)
    assert not params.use_rate
    s = 0.2
    scaled = dataclasses.replace(params, sigma_v=params.sigma_v * np.sqrt(s))
    got = _run(params, data, q_scale=np.array([s, 1.0]))
    np.testing.assert_allclose(got, _run(scaled, data), rtol=1e-9, atol=1e-15)


def test_moves_apply_what_they_say() -> None:
    """r_scale scales the assumed ADS σ, the factors land in the kernel's inputs, a reset adds
    (f σ0)² to the nine calibration variances only, and nominal moves change nothing."""
    cfg = load_scenario("thermal_snap", SHORT)
    data = simulate(cfg, 5, [0, 1, 2])
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 3)
    kf.initialize(data.ads_q[:, 0])
    kf.step_data(data, 0, 200, 1.0)
    before = kf.P.copy()
    kappa = apply_moves(kf, Moves.nominal(3, 0.5))
    np.testing.assert_array_equal(kappa, 0.5)
    np.testing.assert_array_equal(kf.P, before)
    moves = Moves(
        kappa=np.ones(3),
        q_att=np.array([1.0, 2.0, 1.0]),
        q_bias=np.array([3.0, 1.0, 1.0]),
        r_scale=np.array([1.0, 1.0, 2.0]),
        reset=np.array([0.0, 0.1, 0.3]),
    )
    apply_moves(kf, moves)
    np.testing.assert_array_equal(kf.q_scale, [[1.0, 3.0], [2.0, 1.0], [1.0, 1.0]])
    np.testing.assert_allclose(kf.sigma_a, kf.params.sigma_a * np.array([1.0, 1.0, 2.0]))
    after = kf.P
    np.testing.assert_array_equal(after[0], before[0])  # no reset: untouched, bit for bit
    prior = kf.params.p0_sigma[6:15]
    for row, f in ((1, 0.1), (2, 0.3)):
        added = np.diag(after[row] - before[row])
        np.testing.assert_allclose(added[6:15], (f * prior) ** 2, rtol=1e-9)
        np.testing.assert_allclose(added[:6], 0.0, atol=1e-30)
        off = (after[row] - before[row]) - np.diag(np.diag(after[row] - before[row]))
        assert np.max(np.abs(off)) <= 1e-12 * np.max(np.abs(before[row]))
    with pytest.raises(ValueError, match="r_scale"):
        apply_moves(kf, dataclasses.replace(moves, r_scale=np.array([1.0, -1.0, 1.0])))


def test_control_strings_and_spaces() -> None:
    cfg = load_scenario("thermal_snap", SHORT)
    assert parse_controls("reset+kappa") == ("kappa", "reset")
    assert parse_controls("blocks+r_scale") == ("kappa", "q_att", "q_bias", "r_scale")
    for bad, msg in (("kapa", "unknown control"), ("kappa+blocks", "blocks"),
                     ("reset+reset", "twice")):  # fmt: skip
        with pytest.raises(ValueError, match=msg):
            parse_controls(bad)
    one = ControlMap(cfg, "kappa", "discrete")
    assert one.space == gym.spaces.Discrete(11)
    multi = ControlMap(cfg, "kappa+reset+r_scale", "discrete")
    assert list(multi.space.nvec) == [11, 5, 7]  # type: ignore[attr-defined]
    box = ControlMap(cfg, "blocks+reset", "continuous")
    assert box.space.shape == (4,)
    v = box.values(np.array([[-1.0, -1.0, 1.0, -0.5], [1.0, 1.0, -1.0, 1.0]]), 2)
    np.testing.assert_allclose(v[:, 0], [0.01, 100.0])  # κ: ends of the action set
    np.testing.assert_allclose(v[:, 1:3], [[0.1, 10.0], [10.0, 0.1]])
    np.testing.assert_allclose(v[:, 3], [0.0, 0.3])  # reset: none below 0
    with pytest.raises(ValueError, match="outside"):
        multi.values(np.array([[0, 5, 0]]), 1)
    with pytest.raises(ValueError, match="finite"):
        box.values(np.array([[0.0, 0.0, 0.0, 1.5]]), 1)


@pytest.mark.parametrize("base", [None, "nis-rule", "glr"])
def test_actions_round_trip_through_moves(base: str | None) -> None:
    """Every discrete action maps to moves whose nearest action is itself; the neutral action
    is the nominal moves (a residual's: the base's own decision)."""
    cfg = load_scenario("thermal_snap", SHORT)
    cmap = ControlMap(cfg, "blocks+reset+r_scale", "discrete", base=base, n=64)
    rng = np.random.default_rng(0)
    base_moves = None
    if cmap.base is not None:
        base_moves = Moves(
            kappa=10.0 ** rng.uniform(-2, 2, 64), q_att=np.ones(64), q_bias=np.ones(64),
            r_scale=np.ones(64), reset=rng.choice([0.0, 0.05], 64),
        )  # fmt: skip
    acts = np.stack([rng.integers(0, n, 64) for n in cmap.space.nvec], axis=1)  # type: ignore[attr-defined]
    moves = cmap.moves(acts, 64, base_moves)
    again = cmap.actions_of(moves, base_moves)
    if base is None:
        np.testing.assert_array_equal(again, acts)
    else:  # a veto where the rule does not reset is no reset either: the moves are the same
        for got, want in zip(
            cmap.moves(again, 64, base_moves).fields(), moves.fields(), strict=True
        ):
            np.testing.assert_array_equal(got, want)
        vetoed = cmap.moves(np.tile([2, 2, 2, 0, 2], (64, 1)), 64, base_moves)
        np.testing.assert_array_equal(vetoed.reset, 0.0)
    neutral = cmap.moves(np.tile(cmap.neutral(), (64, 1)), 64, base_moves)
    np.testing.assert_array_equal(neutral.q_att, 1.0)
    np.testing.assert_array_equal(neutral.r_scale, 1.0)
    if base_moves is None:
        np.testing.assert_array_equal(neutral.reset, 0.0)
        np.testing.assert_array_equal(neutral.kappa, 1.0)
    else:
        np.testing.assert_array_equal(neutral.kappa, base_moves.kappa)
        np.testing.assert_array_equal(neutral.reset, base_moves.reset)


def test_residual_nis_rule_with_neutral_actions_is_the_nis_rule_method() -> None:
    """The residual on base nis-rule, corrected by nothing, runs the nis-rule method: the same
    estimates bit for bit, trial by trial."""
    cfg = load_scenario("thermal_snap_random", SHORT)
    data = simulate(cfg, 11, [0, 1, 2, 3])
    method = resolve_method("nis-rule").method(cfg, data)
    driver = EpisodeDriver(4, cfg, "discrete", "oracle", None, 10.0, "v4",
                           controls="kappa+reset", base="nis-rule", expert="neutral")  # fmt: skip
    driver.core.load(data)
    driver.restart_base(np.arange(4))
    est = []
    for _ in range(driver.core.episode_steps):
        out = driver.step(driver.expert_actions())
        est.append(out.est)
    got = np.concatenate(est, axis=1)[:, : data.n_epochs]
    np.testing.assert_array_equal(got, method.est)


def test_move_schedule_of_kappa_alone_is_the_kappa_schedule() -> None:
    cfg = load_scenario("thermal_snap_random", SHORT)
    data = simulate(cfg, 12, [0, 1])
    rng = np.random.default_rng(1)
    kappa = 10.0 ** rng.uniform(-2, 2, (2, 60))
    got = run_moves(cfg, data, MoveSchedule.nominal(10, kappa))
    want = run_schedule(cfg, data, np.repeat(kappa, 10, axis=1))
    np.testing.assert_array_equal(got.est, want.est)


@pytest.mark.parametrize("controls,base", [("kappa+reset+r_scale", None), ("blocks", "glr")])
def test_single_and_batched_v4_give_the_same_episodes(controls: str, base: str | None) -> None:
    kw = dict(scenario="thermal_snap_random", overrides=SHORT, reward="relative_state_gain",
              controls=controls, base=base)  # fmt: skip
    singles = [gym.make("qkf/TransferAlignment-v4", **kw) for _ in range(3)]
    vec = gym.make_vec(
        "qkf/TransferAlignment-v4", num_envs=3, vectorization_mode="vector_entry_point", **kw
    )
    obs_v, _ = vec.reset(seed=20)
    obs_s = np.stack([e.reset(seed=20 + i)[0] for i, e in enumerate(singles)])
    np.testing.assert_array_equal(obs_v, obs_s)
    vec.single_action_space.seed(2)
    for _ in range(singles[0].unwrapped.episode_steps):  # type: ignore[attr-defined]
        acts = np.stack([vec.single_action_space.sample() for _ in range(3)])
        obs_v, r_v, *_ = vec.step(acts)
        outs = [e.step(a) for e, a in zip(singles, acts, strict=True)]
        np.testing.assert_array_equal(obs_v, np.stack([o[0] for o in outs]))
        # the reward's sums over a batch round in the last bit (numpy's pairwise sums)
        np.testing.assert_allclose(r_v, np.array([o[1] for o in outs]), rtol=1e-12)
    assert obs_v.shape == (3, 24) and np.all(np.isfinite(obs_v))


def test_slow_nis_means_are_exponential_windows_of_the_period_nis() -> None:
    """Entries 15–18 by hand: m ← m + (1 − e^{−T/τ})(x − m) from m = 1 over the period's mean
    attitude (entry 4) and rate (entry 5) NIS / 3, shown as log10."""
    env = gym.make("qkf/TransferAlignment-v4", scenario="thermal_snap_random", overrides=SHORT,
                   reward="oracle")  # fmt: skip
    env.reset(seed=3)
    m = np.ones(4)
    for _ in range(40):
        obs, *_ = env.step(5)
        x = 10.0 ** obs[4:6].astype(float)  # the period's NIS / 3 (above the floor here)
        for j, tau in enumerate(np.repeat(SLOW_WINDOWS_S, 2)):
            a = 1.0 - np.exp(-10.0 / tau)
            m[j] += a * (x[j % 2] - m[j])
        np.testing.assert_allclose(obs[15:19], np.log10(m), atol=2e-5)


def test_rule_expert_follows_the_glr_decision() -> None:
    """expert='glr' on non-residual kappa+reset answers glr's κ and, after an alarm, the reset
    nearest glr's size; it resets somewhere on a family with jumps."""
    cfg = load_scenario("thermal_snap_random")
    driver = EpisodeDriver(8, cfg, "discrete", "oracle", None, 10.0, "v4",
                           controls="kappa+reset", expert="glr")  # fmt: skip
    for i in range(8):
        driver.rngs[i] = np.random.default_rng(100 + i)
    driver.reset_envs(np.arange(8))
    cmap = driver.controls
    assert cmap is not None
    glr_kappa = cmap.actions_of(Moves.nominal(1, cfg.adaptive.glr.kappa))[0, 0]
    resets = 0
    for _ in range(driver.core.episode_steps):
        acts = driver.expert_actions()
        assert np.all(acts[:, 0] == glr_kappa)
        resets += int(np.sum(acts[:, 1] > 0))
        driver.step(acts)
    assert resets >= 1


def test_hindsight_moves_only_improves_and_reproduces_its_score() -> None:
    """Each stage's score is no higher than the one before, and the final schedule run again
    scores what the search says (the search and run_moves agree)."""
    over = [*SHORT, "adaptive.hindsight.blocks_s=[200,100]", "adaptive.hindsight.restarts=0"]
    cfg = load_scenario("ads_mismatch_random", over)
    data = simulate(cfg, 9000, [0, 1])
    out = resolve_method("hindsight-moves:kappa+reset+r_scale").method(cfg, data)
    scores = out.logs["hindsight_moves_scores"]
    assert np.all(np.diff(scores, axis=1) <= 1e-12)
    final = estimate_scores(cfg, out.est, data, cfg.adaptive.tuned.metric)
    np.testing.assert_allclose(final, scores[:, -1], rtol=1e-9)


def test_a_v4_policy_is_judged_with_the_moves_it_makes(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """policy:PATH of a residual v4 model: the benchmark's estimates are those of the same
    policy driving the environment by hand, and the moves it made are in the logs."""
    import yaml
    from stable_baselines3 import PPO

    from envs.transfer_alignment.sb3 import BatchedTransferAlignmentSB3Env

    kw = dict(controls="kappa+reset+r_scale", base="glr")
    venv = BatchedTransferAlignmentSB3Env(
        2, "thermal_snap_random", reward="oracle", overrides=SHORT, observation="v4", **kw
    )
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=8, seed=0, device="cpu")
    model.save(tmp_path / "model.zip")
    settings = {"agent": "ppo", "env": "qkf/TransferAlignment-v4", "env_kwargs": kw,
                "scenario": "thermal_snap_random", "reward": "oracle"}  # fmt: skip
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(settings))
    cfg = load_scenario("thermal_snap_random", SHORT)
    data = simulate(cfg, 7, [0, 1, 2])
    out = resolve_method(f"policy:{tmp_path / 'model.zip'}").method(cfg, data)
    driver = EpisodeDriver(3, cfg, "discrete", "oracle", None, 10.0, "v4", **kw)
    obs = driver.core.load(data)
    driver.restart_base(np.arange(3))
    est, made = [], []
    for _ in range(driver.core.episode_steps):
        action, _ = model.predict(obs, deterministic=True)
        step = driver.step(action)
        assert step.moves is not None
        made.append(step.moves.r_scale)
        est.append(step.est)
        obs = step.obs
    np.testing.assert_array_equal(out.est, np.concatenate(est, axis=1)[:, : data.n_epochs])
    np.testing.assert_array_equal(out.logs["moves_r_scale"], np.stack(made, axis=1))


def test_mixture_tuned_bases_run_the_rule_with_the_mixed_baselines_settings(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """base='glr-tuned-mixed' runs GLR with what glr-tuned finds on the training mixture (the
    tuning is stubbed here: it is the tuner's to test), at the judged step and duration."""
    from envs.transfer_alignment.controls import BASES
    from qkf.transfer_alignment.methods import tuned

    seen = {}
    real = tuned.TUNED_METHODS["glr-tuned"]

    def prepare(cfg):  # type: ignore[no-untyped-def]
        seen["events"] = cfg.scenario.random_events
        seen["duration"] = cfg.scenario.duration_s
        settings = (("threshold", 7.5), ("reset_ppm", 300.0), ("kappa", 2.5))
        return tuned.TunedSetting(real, settings)

    stub = type("Stub", (), {"prepare": staticmethod(prepare)})()
    monkeypatch.setitem(tuned.TUNED_METHODS, "glr-tuned", stub)
    cfg = load_scenario("thermal_snap_random", SHORT)
    base = BASES["glr-tuned-mixed"](cfg, 2, 10.0)
    mixture = load_scenario("mixed_random").scenario.random_events
    assert seen == {"events": mixture, "duration": 600.0}
    assert base.rule.settings.threshold == 7.5  # type: ignore[attr-defined]
    np.testing.assert_array_equal(base.start().kappa, 2.5)
    np.testing.assert_allclose(base.fraction, 300e-6 / 1500e-6)  # type: ignore[attr-defined]


def test_r_step_moves_a_persistent_level_within_the_grid() -> None:
    """r_step: each action moves the episode's r one grid step (or keeps it); the level holds
    between steps, stops at the grid's ends, restarts at 1 with the episode; the expert's
    mapping answers the step toward the wanted r."""
    from qkf.transfer_alignment.moves import R_SCALES

    cfg = load_scenario("thermal_snap", SHORT)
    cmap = ControlMap(cfg, "kappa+r_step", "discrete", n=2)
    assert list(cmap.space.nvec) == [11, 3]  # type: ignore[attr-defined]
    up, keep, down = [5, 2], [5, 1], [5, 0]
    seen = [cmap.moves(np.array([a, keep]), 2).r_scale for a in (up, up, keep, down)]
    np.testing.assert_allclose([s[0] for s in seen], [2**0.5, 2.0, 2.0, 2**0.5])
    np.testing.assert_array_equal([s[1] for s in seen], 1.0)
    for _ in range(10):
        top = cmap.moves(np.array([up, down]), 2).r_scale
    np.testing.assert_array_equal(top, [R_SCALES[-1], R_SCALES[0]])
    cmap.restart(np.array([0]))
    np.testing.assert_array_equal(cmap.moves(np.array([keep, keep]), 2).r_scale, [1.0, 0.5])
    wanted = Moves.nominal(2)
    wanted = dataclasses.replace(wanted, r_scale=np.array([4.0, 0.5]))
    np.testing.assert_array_equal(cmap.actions_of(wanted)[:, 1], [2, 1])
    with pytest.raises(ValueError, match="r_step"):
        parse_controls("r_scale+r_step")


def test_kappa_step_moves_the_residual_factor_level() -> None:
    """kappa_step on a residual: the factor on the rule's κ moves one grid step per action and
    holds; without a base it moves along the action set from the nominal κ."""
    cfg = load_scenario("thermal_snap", SHORT)
    base = Moves.nominal(1, 2.0)
    cmap = ControlMap(cfg, "kappa_step+r_step", "discrete", base="glr", n=1)
    kappas = [cmap.moves(np.array([[a, 1]]), 1, base).kappa[0] for a in (0, 1, 0, 2)]
    np.testing.assert_allclose(kappas, [2.0 * 10**-0.5, 2.0 * 10**-0.5, 0.2, 2.0 * 10**-0.5])
    plain = ControlMap(cfg, "kappa_step", "discrete", n=1)
    assert plain.space == gym.spaces.Discrete(3)
    np.testing.assert_allclose(plain.moves(np.array([2]), 1).kappa, 10**0.4)
    with pytest.raises(ValueError, match="kappa_step"):
        parse_controls("kappa+kappa_step")


def test_hindsight_moves_searches_what_a_stepped_control_can_reach() -> None:
    """r_step and kappa_step move r and κ: their hindsight searches those moves."""
    from qkf.transfer_alignment.methods.hindsight_moves import controlled_moves

    assert controlled_moves("kappa_step+reset+r_step") == ("kappa", "reset", "r_scale")
    with pytest.raises(ValueError, match="unknown control"):
        controlled_moves("r_stp")
