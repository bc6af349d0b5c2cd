"""``qkf dataset`` (envs/transfer_alignment/datasets.py): a method's decisions as the
environment's moves (kf's constant κ, glr's re-openings as resets a period later), the replay of
nis-rule through the environment reproducing the method's estimates, the Minari dataset read back
(arrays, metadata, returns the environment gives for the stored actions), and the command's
refusals (exit 2, nothing written) and reproducibility (docs/environment.md, "Datasets")."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from typer.testing import CliRunner

from envs.transfer_alignment.controls import ControlMap
from envs.transfer_alignment.datasets import (
    DatasetPlan,
    dataset_id,
    dataset_of,
    datasets_path,
    make_datasets,
    method_moves,
    plan_datasets,
    record_episodes,
    run_method,
)
from qkf.cli import app
from qkf.transfer_alignment.config import load_config
from qkf.transfer_alignment.methods import MethodOutput, resolve_method
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import simulate

minari = pytest.importorskip("minari")

SEED = 5_030_000  # tests: seeds ≥ 5e6 (docs/environment.md, "Seed ranges")
# 300 s of thermal_snap (its rotations 0 … 300 s) with the misalignment jump moved to 150 s, so
# that glr re-opens and nis-rule bursts within 30 periods
SETS = [
    "scenario.duration_s=300",
    "scenario.calibration_jumps=[{t_s: 150, misalignment_urad: 300}]",
]
CONTROLS = "kappa+reset"
REWARD = "relative_state_gain"
PERIOD = 10  # epochs per decision period (10 s at dt 1 s)
runner = CliRunner()


def _cfg(*extra: str) -> Any:
    return load_config("thermal_snap", [*SETS, *extra])


def _moves(cfg: Any, name: str, data: Any) -> tuple[MethodOutput, list[Any]]:
    out = run_method(cfg, resolve_method(name), data)
    return out, method_moves(cfg, out, PERIOD, ControlMap(cfg, CONTROLS, "discrete"))


def test_kf_moves_are_its_constant_kappa_and_that_kappa_s_action() -> None:
    kappas = np.asarray(_cfg().adaptive.actions.values())
    cfg = _cfg(f"run.kappa={float(kappas[3])!r}")
    data = simulate(cfg, SEED, 2)
    _, moves = _moves(cfg, "kf", data)
    assert len(moves) == 30
    for m in moves:
        np.testing.assert_array_equal(m.kappa, kappas[3])
        np.testing.assert_array_equal(m.reset, 0.0)
        for f in (m.q_att, m.q_bias, m.r_scale):
            np.testing.assert_array_equal(f, 1.0)
    ep = record_episodes(cfg, data, moves, CONTROLS, REWARD, 10.0)
    assert ep.actions.shape == (2, 30, 2)
    np.testing.assert_array_equal(ep.actions[..., 0], 3)  # κ's index in the action set
    np.testing.assert_array_equal(ep.actions[..., 1], 0)  # no reset
    assert ep.infos["on_grid"].all()
    np.testing.assert_array_equal(ep.infos["kappa"][:, 1:], kappas[3])


def test_glr_reopenings_become_resets_at_the_next_period() -> None:
    cfg = _cfg()
    data = simulate(cfg, SEED, 2)
    out, moves = _moves(cfg, "glr", data)
    reopen = out.logs["reopen"]
    assert reopen.any(axis=1).all(), "the jump at 150 s re-opens every trial"
    fraction = cfg.adaptive.glr.reset_ppm * 1e-6 / FilterParams.from_config(cfg).p0_sigma[6]
    resets = np.stack([m.reset for m in moves], axis=1)  # (B, periods)
    for b in range(2):
        periods = np.unique(np.flatnonzero(reopen[b]) // PERIOD)
        expected = np.zeros(30)
        expected[periods + 1] = fraction
        np.testing.assert_array_equal(resets[b], expected)
    np.testing.assert_array_equal(np.stack([m.kappa for m in moves]), cfg.adaptive.glr.kappa)
    # the action is the nearest reset size (0.1 of the prior σ); the move applied is the exact one
    ep = record_episodes(cfg, data, moves, CONTROLS, REWARD, 10.0)
    at = resets > 0.0
    np.testing.assert_array_equal(ep.actions[..., 1][at], 3)
    np.testing.assert_array_equal(ep.actions[..., 1][~at], 0)
    np.testing.assert_array_equal(ep.infos["reset"][:, 1:], resets)
    np.testing.assert_array_equal(ep.infos["on_grid"][:, 1:], ~at)


def test_a_reopening_in_the_last_period_has_no_next_period() -> None:
    """By hand: re-openings at epochs 0, 9 (period 0), 10 (period 1) and 25 (the last, cut
    short) give resets at the starts of periods 1 and 2 only."""
    cfg = _cfg()
    b, n = 2, 25
    reopen = np.zeros((b, n), dtype=bool)
    reopen[0, [0, 9]] = True
    reopen[1, [10, 24]] = True
    kappa = np.full((b, n), 0.5)
    kappa[:, 10:] = 2.0
    kappa[1, 20] = np.nan  # a diverged trial's κ: replaced by the nominal κ
    out = MethodOutput(np.zeros((b, n, 16)), np.zeros(b, bool), kappa, {"reopen": reopen})
    moves = method_moves(cfg, out, PERIOD, ControlMap(cfg, CONTROLS, "discrete"))
    assert len(moves) == 3
    f = cfg.adaptive.glr.reset_ppm * 1e-6 / FilterParams.from_config(cfg).p0_sigma[6]
    np.testing.assert_array_equal(np.stack([m.reset for m in moves], 1), [[0, f, 0], [0, 0, f]])
    np.testing.assert_array_equal(np.stack([m.kappa for m in moves], 1), [[0.5, 2, 2], [0.5, 2, 1]])


def test_logged_moves_are_replayed_as_they_are() -> None:
    cfg = _cfg()
    b, periods = 2, 3
    logged = {
        "kappa": np.full((b, periods), 0.1),
        "q_att": np.full((b, periods), 10.0),
        "q_bias": np.ones((b, periods)),
        "r_scale": np.full((b, periods), 2.0),
        "reset": np.array([[0.0, 0.3, 0.0], [0.01, 0.0, 0.0]]),
    }
    out = MethodOutput(np.zeros((b, 30, 16)), np.zeros(b, bool), None, {})
    out.logs["moves"] = logged  # type: ignore[assignment]
    controls = ControlMap(cfg, CONTROLS, "discrete")
    moves = method_moves(cfg, out, PERIOD, controls)
    for name in logged:
        np.testing.assert_array_equal(np.stack([getattr(m, name) for m in moves], 1), logged[name])
    flat = MethodOutput(out.est, out.diverged, None, {f"moves_{k}": v for k, v in logged.items()})
    again = method_moves(cfg, flat, PERIOD, controls)
    assert all(
        np.array_equal(x, y) for m, n in zip(moves, again, strict=True)
        for x, y in zip(m.fields(), n.fields(), strict=True)
    )  # fmt: skip
    with pytest.raises(ValueError, match="shape"):
        method_moves(cfg, flat, 5, controls)


def test_replaying_nis_rule_reproduces_its_estimates() -> None:
    """The environment's filter with nis-rule's κ per period is the method's filter: the same
    estimates, bit for bit (its period, 10 s, is the environment's)."""
    cfg = _cfg()
    assert cfg.adaptive.nis_rule.period_s == 10.0
    data = simulate(cfg, SEED, 3)
    out, moves = _moves(cfg, "nis-rule", data)
    kappas = np.stack([m.kappa for m in moves], axis=1)
    assert (kappas == cfg.adaptive.nis_rule.kappa_burst).any(axis=1).all()  # it burst
    ep = record_episodes(cfg, data, moves, CONTROLS, REWARD, 10.0, keep_estimates=True)
    assert ep.est is not None
    assert np.max(np.abs(ep.est - out.est)) <= 1e-12
    np.testing.assert_array_equal(ep.est, out.est)
    assert ep.infos["on_grid"].all()  # κ_base and κ_burst are actions of the set


def _plan(out: Path, methods: str = "kf,glr,nis-rule", trials: int = 3) -> DatasetPlan:
    return plan_datasets("thermal_snap", methods, trials, SEED, CONTROLS, REWARD, 10.0, out, SETS)


def test_the_dataset_loads_with_minari_and_holds_the_episodes(tmp_path: Path) -> None:
    plan = _plan(tmp_path / "ds")
    written = make_datasets(plan)
    assert written == [tmp_path / "ds" / i for i in plan.ids]
    assert plan.ids[2] == "qkf/transfer-alignment-v4-thermal_snap-nis-rule-v0"
    assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == ["qkf"]  # no staging left
    nis_rule = plan.methods[2]
    recorded, _ = dataset_of(plan, nis_rule)
    with datasets_path(tmp_path / "ds"):
        ds = minari.load_dataset(plan.ids[2])
    assert ds.total_episodes == 3 and ds.total_steps == 90
    assert ds.action_space == ControlMap(plan.cfg, CONTROLS, "discrete").space
    assert ds.observation_space.shape == (24,)
    meta = ds.storage.metadata
    assert meta["algorithm_name"] == "nis-rule"
    q = meta["qkf"]
    assert (q["scenario"], q["seed"], q["trial_ids"]) == ("thermal_snap", SEED, [0, 1, 2])
    assert (q["controls"], q["reward"], q["period_s"]) == (CONTROLS, REWARD, 10.0)
    assert q["overrides"] == SETS
    episodes = list(ds.iterate_episodes())
    assert [e.id for e in episodes] == [0, 1, 2]
    assert [m["trial_id"] for m in ds.storage.get_episode_metadata(range(3))] == [0, 1, 2]
    for i, e in enumerate(episodes):
        mine = recorded.episode(i)
        np.testing.assert_array_equal(e.observations, mine["observations"])
        np.testing.assert_array_equal(e.actions, mine["actions"])
        np.testing.assert_array_equal(e.rewards, mine["rewards"])
        np.testing.assert_array_equal(e.terminations, mine["terminations"])
        np.testing.assert_array_equal(e.truncations, mine["truncations"])
        assert e.truncations[-1] and not e.truncations[:-1].any()
        for key in ("kappa", "reset", "t_s", "on_grid"):
            np.testing.assert_array_equal(e.infos[key], mine["infos"][key])
        assert e.infos["errors"].shape == (31, 15)
        _check_against_the_environment(plan, e, trial=i)


def _check_against_the_environment(plan: DatasetPlan, episode: Any, trial: int) -> None:
    """The registered environment, on the episode's trial, stepped with the stored actions:
    the same observations, and the rewards' sum is its return."""
    env = gym.make(
        "qkf/TransferAlignment-v4", scenario="thermal_snap", overrides=SETS, controls=CONTROLS,
        reward=REWARD,
    )  # fmt: skip
    env.reset(seed=0)
    core = env.unwrapped._driver.core  # type: ignore[attr-defined]
    first = core.load(simulate(plan.cfg, SEED, [trial]))
    np.testing.assert_array_equal(first[0], episode.observations[0])
    total, steps = 0.0, 0
    for action in episode.actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        total += float(reward)
        steps += 1
        np.testing.assert_array_equal(obs, episode.observations[steps])
        if terminated or truncated:
            break
    assert steps == len(episode.rewards)
    assert total == pytest.approx(float(np.sum(episode.rewards)), rel=1e-12, abs=1e-12)


def _dataset_cmd(out: Path, *args: str, methods: str = "kf") -> Any:
    sets = [a for s in SETS for a in ("--set", s)]
    return runner.invoke(
        app,
        ["dataset", "thermal_snap", "--methods", methods, "--trials", "2", "--seed", str(SEED),
         "--out", str(out), "--quiet", *sets, *args],
    )  # fmt: skip


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
    }


def test_the_command_refuses_before_any_work(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    first = _dataset_cmd(out)
    assert first.exit_code == 0, first.output
    assert "wrote" in first.output
    before = _snapshot(out)
    again = _dataset_cmd(out, methods="nis-rule,kf")
    assert again.exit_code == 2
    assert "exists" in again.output and "transfer-alignment-v4-thermal_snap-kf-v0" in again.output
    assert _snapshot(out) == before  # nothing written, not even nis-rule's dataset
    for args, methods, word in (
        ((), "kf,no-such-method", "--methods"),
        (("--controls", "kappa+bogus"), "kf", "--controls"),
        (("--controls", "kappa+blocks"), "kf", "--controls"),
        (("--reward", "nope"), "kf", "--reward"),
        (("--set", "scenario.dt_s=-1"), "kf", "scenario.dt_s"),
        (("--env", "qkf/RedundantGyroCalibration-v3"), "kf", "qkf/TransferAlignment-v4"),
        (("--env", "qkf/NoSuchEnv-v0"), "kf", "NoSuchEnv"),
    ):
        fresh = tmp_path / f"new_{word.strip('-')}"
        res = _dataset_cmd(fresh, *args, methods=methods)
        assert res.exit_code == 2, res.output
        assert word in res.output
        assert not fresh.exists()
    bad = runner.invoke(
        app, ["dataset", "no_such_scenario", "--methods", "kf", "--out", str(tmp_path / "x")]
    )
    assert bad.exit_code == 2 and "no_such_scenario" in bad.output
    assert not (tmp_path / "x").exists()


def test_same_seed_gives_identical_datasets(tmp_path: Path) -> None:
    for name in ("a", "b"):
        res = _dataset_cmd(tmp_path / name, methods="glr")
        assert res.exit_code == 0, res.output
    ident = dataset_id("thermal_snap", "glr")
    loaded = []
    for name in ("a", "b"):
        with datasets_path(tmp_path / name):
            loaded.append(list(minari.load_dataset(ident).iterate_episodes()))
    assert len(loaded[0]) == len(loaded[1]) == 2
    for x, y in zip(*loaded, strict=True):
        for key in ("observations", "actions", "rewards", "terminations", "truncations"):
            np.testing.assert_array_equal(getattr(x, key), getattr(y, key))
        for key in x.infos:
            np.testing.assert_array_equal(x.infos[key], y.infos[key])
