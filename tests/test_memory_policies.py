"""Issue 21: observation v3 (no clock) and its timed ablation, the whole-state reward, the
recurrent agent and frame-stacked MLPs, acting batched over trials, and the refusals of a model
that does not match its config."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from agents.config import load_train_config
from agents.policy import Policy, run_policy
from agents.training import train
from envs.transfer_alignment import BatchedEpisodes
from envs.transfer_alignment.observations import NIS_WINDOW
from qkf.cli import app
from qkf.transfer_alignment.config import ConfigError, load_config
from qkf.transfer_alignment.filter import TransferAlignmentKF
from qkf.transfer_alignment.judging import state_weights
from qkf.transfer_alignment.methods.base import per_epoch
from qkf.transfer_alignment.methods.oracle import run_schedule
from qkf.transfer_alignment.metrics import state_errors, window_masks
from qkf.transfer_alignment.params import FilterParams
from qkf.transfer_alignment.scenario import simulate
from tests.conftest import CONFIGS, TRAINING

SHORT = "scenario.duration_s=300"
SEED = 5_021_000  # tests: seeds ≥ 5e6 (docs/environment.md, "Seed ranges")


def _episodes(observation: str, reward: str = "likelihood", n: int = 3) -> BatchedEpisodes:
    cfg = load_config(CONFIGS / "mixed_random.yaml", [SHORT])
    core = BatchedEpisodes(cfg, n, reward, observation=observation)
    core.load(simulate(cfg, SEED, n))
    return core


def _run(core: BatchedEpisodes, kappa_index: np.ndarray) -> list[np.ndarray]:
    kappas = core.kappas
    out = []
    for idx in kappa_index:
        step = core.step(kappas[idx], idx / (kappas.size - 1))
        out.append(step)
    return out


def test_v3_is_v2_without_the_clock_and_v3_time_adds_it() -> None:
    """v3 carries v2's evidence (same values), the calibration level split into its two blocks,
    and no elapsed time; v3-time is v3 and the elapsed fraction."""
    rng = np.random.default_rng(SEED)
    schedule = rng.integers(0, 11, size=(12, 3))
    v2 = [s.obs for s in _run(_episodes("v2"), schedule)]
    v3 = [s.obs for s in _run(_episodes("v3"), schedule)]
    timed = [s.obs for s in _run(_episodes("v3-time"), schedule)]
    kept_v2 = [0, 1, 3, 4, 5, 6, 7, 8, 9, 11, 12]  # all but the calibration level and the time
    kept_v3 = [0, 1, 4, 5, 8, 9, 10, 11, 12, 13, 14]
    for k, (a, b, c) in enumerate(zip(v2, v3, timed, strict=True)):
        assert b.shape == (3, 15) and c.shape == (3, 16)
        np.testing.assert_allclose(b[:, kept_v3], a[:, kept_v2], atol=1e-6)
        # v2's calibration level is the mean over 9 states; v3 gives 3 scale factors, 6 ma
        np.testing.assert_allclose((3 * b[:, 2] + 6 * b[:, 3]) / 9, a[:, 2], atol=1e-5)
        np.testing.assert_array_equal(c[:, :15], b)
        np.testing.assert_allclose(c[:, 15], min(1.0, (k + 1) * 10 / 300), atol=1e-6)
        assert not np.any(np.isclose(b, a[:, 10:11]).all(axis=0))  # no entry is the clock


def test_v3_windowed_nis_per_block_by_hand() -> None:
    """Entries 6, 7: log10 of the mean, over the last NIS_WINDOW periods, of the period's mean
    attitude (rate) NIS / 3, recomputed from a filter run here on the same data."""
    cfg = load_config(CONFIGS / "mixed_random.yaml", [SHORT])
    data = simulate(cfg, SEED, 2)
    core = BatchedEpisodes(cfg, 2, "likelihood", observation="v3")
    core.load(data)
    kf = TransferAlignmentKF(FilterParams.from_config(cfg), 2)
    kf.initialize(data.ads_q[:, 0])
    has_meas = np.broadcast_to(data.has_meas, (2, data.n_epochs))
    att, rate = [], []
    for k in range(NIS_WINDOW + 3):
        out = core.step(np.ones(2), np.full(2, 0.5))
        sl = slice(k * core.period, (k + 1) * core.period)
        rec = kf.step(
            data.gyro[:, sl], data.ads_q[:, sl], data.ads_rate[:, sl], has_meas[:, sl], 1.0
        )
        att.append(np.nanmean(rec.nis_att, axis=1) / 3.0)
        rate.append(np.nanmean(rec.nis_rate, axis=1) / 3.0)
    np.testing.assert_allclose(
        out.obs[:, 6], np.log10(np.mean(att[-NIS_WINDOW:], axis=0)), rtol=1e-5
    )
    np.testing.assert_allclose(
        out.obs[:, 7], np.log10(np.mean(rate[-NIS_WINDOW:], axis=0)), rtol=1e-5, atol=1e-6
    )


@pytest.mark.parametrize("reward", ["state_gain", "relative_state_gain"])
def test_state_gain_returns_by_the_replayed_schedules(reward: str) -> None:
    """Summed over an episode, state_gain is MS_kf − MS_agent of state_settled, and
    relative_state_gain is 1 − MS_agent / MS_kf, both computed here independently from the
    replayed κ schedules."""
    cfg = load_config(CONFIGS / "mixed_random.yaml", [SHORT])
    data = simulate(cfg, SEED + 1, 2)
    core = BatchedEpisodes(cfg, 2, reward, observation="v3")
    core.load(data)
    rng = np.random.default_rng(SEED + 2)
    schedule = rng.integers(0, core.kappas.size, size=(core.episode_steps, 2))
    total = np.zeros(2)
    for idx in schedule:
        total += core.step(core.kappas[idx], idx / (core.kappas.size - 1)).reward
    kappa = per_epoch(core.kappas[schedule].T, core.period, data.n_epochs)
    w = state_weights(cfg)
    settled = window_masks(data.t, cfg.run.settled_s)["settled"]

    def ms(kappa_per_epoch: np.ndarray) -> np.ndarray:
        est = run_schedule(cfg, data, kappa_per_epoch).est
        err = state_errors(est, data.q_true, data.bias, data.calib)
        return np.mean((err[:, settled] / w) ** 2, axis=(1, 2))

    ms_kf, ms_agent = ms(np.full_like(kappa, core.nominal_kappa)), ms(kappa)
    expect = ms_kf - ms_agent if reward == "state_gain" else 1.0 - ms_agent / ms_kf
    np.testing.assert_allclose(total, expect, rtol=1e-6, atol=1e-9)
    assert np.any(np.abs(total) > 1e-6)  # the schedule made a difference


def _tiny(agent_cfg: str, out: Path, *sets: str) -> Path:
    cfg = load_train_config(
        TRAINING / agent_cfg,
        [
            "total_steps=64",
            "n_envs=2",
            f"overrides=[{SHORT}]",
            "eval={episodes: 1, seed: 2000000, every_steps: 64}",
            *sets,
        ],
    )
    return train(cfg, out, progress=False)


@pytest.fixture(scope="module")
def tiny_models(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("memory_models")
    small = "hyperparams={n_steps: 16, batch_size: 32, n_epochs: 1}"
    return {
        "lstm": _tiny("train_rppo_mixed_v3.yaml", root / "lstm", small,
                      "hyperparams.policy_kwargs={lstm_hidden_size: 8, net_arch: [8]}"),
        "stack": _tiny("train_ppo_mixed_v3.yaml", root / "stack", small),
    }  # fmt: skip


@pytest.mark.parametrize("kind", ["lstm", "stack"])
def test_batched_policy_acts_as_one_trial_at_a_time(
    kind: str, tiny_models: dict[str, Path]
) -> None:
    """policy:PATH over 3 trials at once gives each trial the estimates and κ it gets alone:
    the LSTM state and the frame stack are per trial."""
    cfg = load_config(CONFIGS / "mixed_random.yaml", [SHORT])
    data = simulate(cfg, SEED + 3, 3)
    path = str(tiny_models[kind])
    together = run_policy(cfg, data, path)
    for i in range(3):
        alone = run_policy(cfg, simulate(cfg, SEED + 3, [i]), path)
        np.testing.assert_array_equal(alone.kappa[0], together.kappa[i])
        np.testing.assert_allclose(alone.est[0], together.est[i], rtol=0, atol=1e-12)


def test_frame_stack_matches_sb3(tiny_models: dict[str, Path]) -> None:
    """The policy's own stack is SB3's VecFrameStack: same stacked observations."""
    from gymnasium import spaces
    from stable_baselines3.common.vec_env.stacked_observations import StackedObservations

    policy = Policy(tiny_models["stack"])
    size, k = policy.obs_size, policy.frame_stack
    assert k == 4
    box = spaces.Box(-100, 100, (size,), np.float32)
    sb3 = StackedObservations(2, k, box)
    rng = np.random.default_rng(SEED)
    first = rng.normal(size=(2, size)).astype(np.float32)
    expect = sb3.reset(first)
    policy.reset(2)
    policy.act(first)
    np.testing.assert_array_equal(policy._stacked, expect)
    for _ in range(5):
        obs = rng.normal(size=(2, size)).astype(np.float32)
        expect, _ = sb3.update(obs, np.zeros(2, bool), [{}, {}])
        policy.act(obs)
        np.testing.assert_array_equal(policy._stacked, expect)


def _bench(model: Path, out: Path) -> tuple[int, str]:
    res = CliRunner().invoke(
        app,
        ["bench", str(CONFIGS / "mixed_random.yaml"), "--methods", f"kf,policy:{model}",
         "--trials", "2", "--seed", str(SEED), "--set", SHORT, "--out", str(out), "--quiet"],
    )  # fmt: skip
    return res.exit_code, res.output


def _with_config(model: Path, dst: Path, **changes: object) -> Path:
    dst.mkdir()
    shutil.copy(model, dst / model.name)
    cfg = yaml.safe_load((model.parent / "config.yaml").read_text())
    cfg.update(changes)
    (dst / "config.yaml").write_text(yaml.safe_dump(cfg))
    return dst / model.name


@pytest.mark.parametrize(
    ("kind", "changes", "message"),
    [
        ("lstm", {"agent": "ppo"}, "holds a recurrent"),
        ("stack", {"agent": "recurrent_ppo", "frame_stack": 1}, "holds a feed-forward"),
        ("stack", {"env": "qkf/TransferAlignment-v2"}, "another environment version"),
        ("stack", {"frame_stack": 1}, "another environment version"),
    ],
)
def test_a_model_that_does_not_match_its_config_is_refused(
    kind: str, changes: dict[str, object], message: str, tiny_models: dict[str, Path],
    tmp_path: Path,
) -> None:  # fmt: skip
    model = _with_config(tiny_models[kind], tmp_path / "m", **changes)
    code, output = _bench(model, tmp_path / "out")
    assert code == 2, output
    assert message in " ".join(output.split())
    assert not (tmp_path / "out").exists()


def test_the_matching_models_run_in_the_bench(tiny_models: dict[str, Path], tmp_path: Path) -> None:
    for kind, model in tiny_models.items():
        code, output = _bench(model, tmp_path / kind)
        assert code == 0, output
        assert (tmp_path / kind / "trials.csv").is_file()


def test_frame_stack_and_memory_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="frame_stack: recurrent_ppo keeps its own memory"):
        load_train_config(TRAINING / "train_rppo_mixed_v3.yaml", ["frame_stack=2"])
    with pytest.raises(ConfigError, match="frame_stack: the tabular agent"):
        load_train_config(TRAINING / "train_tabular.yaml", ["frame_stack=2"])


def test_policy_goals_gap_share_by_hand() -> None:
    """benchmarks/policy_goals.py: the closed share of the kf-tuned → hindsight gap, against
    a hand computation (RMS 2 → 1.5 → 1: half), and its interval contains the point."""
    import importlib.util

    from qkf.core.stats import resample_counts
    from tests.conftest import ROOT

    spec = importlib.util.spec_from_file_location(
        "policy_goals", ROOT / "benchmarks" / "policy_goals.py"
    )
    assert spec is not None and spec.loader is not None
    goals = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(goals)
    rng = np.random.default_rng(SEED)
    shape = rng.uniform(0.5, 1.5, size=40)
    unit = shape / np.sqrt(np.mean(shape**2))  # RMS exactly 1
    point, lo, hi = goals.gap_closed(
        2.0 * unit, 1.5 * unit, 1.0 * unit, resample_counts(40, 500, 0)
    )
    assert point == pytest.approx(0.5, abs=1e-12)
    # every resample scales the three alike, so the share is 1/2 in each
    assert lo == pytest.approx(0.5, abs=1e-9) and hi == pytest.approx(0.5, abs=1e-9)
    point, lo, hi = goals.gap_closed(
        2.0 * unit, 2.5 * shape, 1.0 * unit, resample_counts(40, 500, 0)
    )
    assert point < 0 and lo <= point <= hi
