"""The problem registry (``qkf.core.problem``), the gyro methods, the paired comparisons of
``qkf.core.versus`` and ``qkf judge`` (``qkf.core.family_judging``): every problem keeps the
protocol and names its environments as ``envs`` registers them; the generic comparison is the
transfer-alignment one; the gyro methods against hand computations; a saved gyro policy judged
on loaded episodes is the policy run in its environment reset with the same seeds."""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from envs import ENVIRONMENTS
from qkf.cli import app
from qkf.core.config import ConfigError
from qkf.core.family_judging import plan_judging, versus_markdown
from qkf.core.problem import PROBLEMS, Problem, TrialRequest, problem_of_env
from qkf.core.stats import resample_counts
from qkf.core.versus import paired_verdict, versus_rows
from qkf.redundant_gyros import hindsight as hs
from qkf.redundant_gyros import load_config as load_gyros
from qkf.redundant_gyros.methods import GYRO_METHODS, resolve_gyro_method

runner = CliRunner()
SHORT = ["scenario.duration_s=160"]  # gyro episodes judged from 100 s (hindsight.SETTLED_S)


@pytest.mark.parametrize("name", ["transfer_alignment", "redundant_gyros"])
def test_a_problem_keeps_the_protocol_and_its_families_load(name: str) -> None:
    prob = PROBLEMS[name]
    assert isinstance(prob, Problem) and prob.name == name
    fam = prob.families
    assert not set(fam.shift) & set(fam.judged)  # the shift group is never trained on
    assert fam.mixture is None or fam.mixture in fam.judged
    assert len(fam.all()) == len(set(fam.all()))
    for family in fam.all():
        prob.load_config(family)  # every family is a preset of the problem
    low, high = prob.seeds.judging
    t_low, t_high = prob.seeds.tuning
    assert high <= t_low or t_high <= low  # nothing judged on a tuning seed
    assert prob.seeds.judges(low) and not prob.seeds.judges(t_low)
    assert len(prob.methods) >= 3


def test_problems_name_the_environments_envs_registers() -> None:
    registered = {name: {e for e in ENVIRONMENTS if ENVIRONMENTS[e].problem == name}
                  for name in PROBLEMS}  # fmt: skip
    for name in PROBLEMS:
        assert set(PROBLEMS[name].env_ids) == registered[name]
        for env_id in PROBLEMS[name].env_ids:
            assert problem_of_env(env_id) is PROBLEMS[name]
    with pytest.raises(KeyError, match="no problem has this environment"):
        problem_of_env("qkf/Nothing-v0")


def test_the_generic_comparison_is_the_transfer_alignment_one() -> None:
    from qkf.transfer_alignment.families import versus_rows as ta_versus_rows
    from qkf.transfer_alignment.metrics import METRIC_COLUMNS, STATE_SETTLED

    rng = np.random.default_rng(5_000_001)
    n, k = 24, len(METRIC_COLUMNS)
    values = {m: rng.lognormal(0.0, 0.5, (n, k)) for m in ("a", "b", "c")}
    ta = ta_versus_rows("fam", values, ["a", "c"], 500, 0.9, 3)
    j = METRIC_COLUMNS.index(STATE_SETTLED)
    core = versus_rows("fam", {m: v[:, j] for m, v in values.items()}, ["a", "c"], 500, 0.9, 3)
    assert ta == core and len(core) == 4
    # by hand: the pooled ratio, the median and P(improve) of the per-trial ratios
    a, b = values["a"][:, j], values["b"][:, j]
    row = core[0]
    assert (row.method, row.other) == ("a", "b")
    assert row.ratio == pytest.approx(np.sqrt(np.sum(a**2) / np.sum(b**2)), rel=1e-12)
    assert row.median == pytest.approx(np.median(a / b), rel=1e-12)
    assert row.p_improve == pytest.approx(np.mean(a < b), rel=1e-12)
    counts = resample_counts(n, 500, 3)
    boot = np.sqrt((counts @ a**2) / (counts @ b**2))
    assert row.lo == pytest.approx(np.percentile(boot, 5.0), rel=1e-9)
    assert paired_verdict(0.8, 0.9, 0.7, 0.95, True) == "better"
    assert paired_verdict(0.8, 1.1, 0.7, 0.95, True) == "inconclusive"
    assert paired_verdict(1.1, 1.2, 1.05, 1.3, True) == "worse"
    assert paired_verdict(0.8, 0.9, 0.7, 0.95, False) == "unjudged"


def _constant_by_hand(ep: hs.Episode, kappa: float) -> float:
    ukf = hs.CompiledUKF(ep)
    x, p = ukf.prior()
    return float(ukf.score(ukf.run(x, p, np.full(ep.n_epochs, kappa), 0, ep.n_epochs)))


def test_gyro_methods_against_hand_computations() -> None:
    cfg = load_gyros("gyro_noise_levels", SHORT)
    prob = PROBLEMS["redundant_gyros"]
    episodes = prob.simulate(cfg, 5_000_020, range(3))
    assert [ep.seed for ep in episodes] == [5_000_020, 5_000_021, 5_000_022]
    tuning = prob.simulate(cfg, 1_000_000, range(2))
    kappas = np.asarray(cfg.environment.actions.values())
    # constant: the κ of the action set best on the tuning episodes, applied to the judged ones
    tuned = [np.mean([_constant_by_hand(ep, k) for ep in tuning]) for k in kappas]
    best = float(kappas[int(np.argmin(tuned))])
    constant = GYRO_METHODS["constant"](cfg, episodes, tuning)
    np.testing.assert_allclose(constant, [_constant_by_hand(ep, best) for ep in episodes],
                               rtol=1e-12)  # fmt: skip
    informed = GYRO_METHODS["level-informed"](cfg, episodes, tuning)
    by_hand = [min(_constant_by_hand(ep, k) for k in kappas) for ep in episodes]
    np.testing.assert_allclose(informed, by_hand, rtol=1e-12)
    hindsight = GYRO_METHODS["hindsight"](cfg, episodes, tuning)
    assert np.all(hindsight <= informed * (1 + 1e-12))  # its search starts at the best constant
    assert np.all(informed <= constant * (1 + 1e-12))
    # the tuned adaptive methods are never worse than the constant on their tuning episodes
    for name in ("clock", "nis-adaptive"):
        on_tuning = GYRO_METHODS[name](cfg, tuning, tuning)
        assert np.mean(on_tuning) <= min(tuned) * (1 + 1e-12), name


def test_gyro_method_specs() -> None:
    assert resolve_gyro_method("c=constant")[0] == "c"
    assert resolve_gyro_method(" clock ")[0] == "clock"
    with pytest.raises(ValueError, match="unknown gyro method 'kf'"):
        resolve_gyro_method("kf")
    with pytest.raises(ValueError, match="empty label"):
        resolve_gyro_method("=constant")
    with pytest.raises(ValueError, match="unknown gyro method factory 'nope'"):
        resolve_gyro_method("nope:x")
    with pytest.raises(ValueError, match="the same label twice"):
        PROBLEMS["redundant_gyros"].method_labels(["constant", "constant"])


def test_a_gyro_policy_judged_on_loaded_episodes_is_the_policy_in_its_environment(
    bare_gyro_policy: str,
) -> None:
    from agents.policy import Policy
    from envs.redundant_gyros.sb3 import BatchedGyroSB3Env

    spec = bare_gyro_policy
    cfg = load_gyros("gyro_noise_levels", SHORT)
    seed, n = 5_000_030, 3
    label, method = resolve_gyro_method(f"policy:{spec}")
    assert label == "policy:gyro_ppo"
    episodes = PROBLEMS["redundant_gyros"].simulate(cfg, seed, range(n))
    j = method(cfg, episodes, [])
    # the same policy stepped through the SB3 environment, reset with the seeds
    policy = Policy(spec)
    env = BatchedGyroSB3Env(n, cfg, observation="v3", reward="oracle",
                            period_s=policy.cfg.period_s)  # fmt: skip
    core = env.episodes
    env.seed(seed)
    obs: Any = env.reset()
    settled = np.array([ep.settled_from for ep in episodes])
    total, chosen = np.zeros(n), set()
    for _ in range(core.episode_steps):
        k0 = core.k.copy()
        action = policy.act(obs)
        chosen |= set(np.asarray(action).ravel().tolist())
        obs, _, _, _ = env.step(action)
        total += core.settled_square(k0, settled)
    np.testing.assert_allclose(j, total / ((core.n_steps - settled) * 4.0), rtol=1e-12)
    assert len(chosen) > 1  # the policy does change κ: the observations matter
    ta_policy = Path(__file__).resolve().parents[1] / "agents" / "zoo" / "best" / "model.zip"
    with pytest.raises(ConfigError, match="not a redundant-gyros environment"):
        resolve_gyro_method(f"policy:{ta_policy}")  # the shipped transfer-alignment policy


def test_judging_refuses_before_any_work() -> None:
    ok: dict[str, object] = {"families": ["gyro_control"], "specs": ["constant", "clock"],
                             "trials": 4}  # fmt: skip
    plan = plan_judging("redundant_gyros", **ok)  # type: ignore[arg-type]
    assert plan.seed == 5_000_000 and plan.focus == ["constant", "clock"]
    last = plan_judging("redundant_gyros", **{**ok, "seed": 5_999_996})  # type: ignore[arg-type]
    assert last.seed == 5_999_996  # its 4 episodes are the range's last 4 seeds
    cases: dict[str, tuple[dict[str, object], str]] = {
        "problem": ({"problem": "nope"}, "unknown problem 'nope'"),
        "family": ({"families": ["steady_random"]}, "--families: steady_random: not a family"),
        "seed": ({"seed": 1_000_000}, "--seed: 1000000 is not a judging seed"),
        "span": (
            {"seed": 5_999_998},
            r"--seed: 4 trials of seed 5999998 draw seeds \[5,999,998, "
            r"6,000,002\), not all of them judging seeds",
        ),
        "method": ({"specs": ["constant", "kf"]}, "--methods: .*unknown gyro method 'kf'"),
        "one": ({"specs": ["constant"]}, "--methods: at least two methods"),
        "focus": ({"focus": ["policy"]}, "--focus: policy: not among"),
        "trials": ({"trials": 1}, "--trials: 1"),
        "config": ({"overrides": ["scenario.dt_s=-1"]}, "(?s)family gyro_control: .*scenario.dt_s"),
    }
    for change, message in cases.values():
        args = {"problem": "redundant_gyros", **ok, **change}
        with pytest.raises(ConfigError, match=message):
            plan_judging(**args)  # type: ignore[arg-type]


def test_qkf_judge_gyros_writes_tables_recomputed_from_its_trials(tmp_path: Path) -> None:
    out = tmp_path / "judged"
    args = ["judge", "redundant_gyros", "--methods", "c=constant,level-informed",
            "--families", "gyro_control,gyro_noise_levels", "--trials", "16", "--focus",
            "level-informed", "--out", str(out), "--no-progress",
            *(x for s in SHORT for x in ("--set", s))]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    with (out / "trials.csv").open() as f:
        trials = list(csv.DictReader(f))
    with (out / "versus.csv").open() as f:
        versus = list(csv.DictReader(f))
    assert [r["family"] for r in versus] == ["gyro_control", "gyro_noise_levels"]
    for row in versus:
        mine = [r for r in trials if r["family"] == row["family"]]
        a = np.array([float(r["level-informed"]) for r in mine])
        b = np.array([float(r["c"]) for r in mine])
        assert len(mine) == 16 and row["method"] == "level-informed" and row["other"] == "c"
        assert float(row["ratio"]) == pytest.approx(np.sqrt(np.sum(a**2) / np.sum(b**2)))
        assert float(row["p_improve"]) == pytest.approx(np.mean(a < b) + 0.5 * np.mean(a == b))
        assert float(row["ratio"]) <= 1.0  # the informed constant is never worse
    info = json.loads((out / "run.json").read_text())
    assert info["problem"] == "redundant_gyros" and info["seed"] == 5_000_000
    assert info["methods"] == {"c": "c=constant", "level-informed": "level-informed"}
    assert "## gyro_control" in (out / "versus.md").read_text()
    # a refused run writes nothing
    bad = tmp_path / "bad"
    res = runner.invoke(app, ["judge", "redundant_gyros", "--methods", "constant,kf", "--out",
                              str(bad), "--no-progress"])  # fmt: skip
    assert res.exit_code == 2 and "unknown gyro method 'kf'" in res.output
    assert not bad.exists()


def test_a_gyro_policy_saved_by_training_is_judged_and_evaluate_points_to_judge(
    tmp_path: Path, bare_gyro_policy: str
) -> None:
    bare = Path(bare_gyro_policy.split("@")[0])
    run = tmp_path / "gyro_run"
    run.mkdir()
    bare.rename(run / "model.zip")
    (run / "config.yaml").write_text(
        "agent: ppo\nenv: qkf/RedundantGyroCalibration-v3\nscenario: gyro_noise_levels\n"
        "action_type: discrete\nreward: mean_square\nperiod_s: 10\n"
    )
    res = runner.invoke(app, ["evaluate", str(run / "model.zip"), "--out", str(tmp_path / "e")])
    assert res.exit_code == 2 and "qkf judge redundant_gyros" in res.output
    assert not (tmp_path / "e").exists()
    out = tmp_path / "judged"
    res = runner.invoke(app, ["judge", "redundant_gyros", "--methods",
                              f"constant,policy:{run / 'model.zip'}", "--families", "gyro_control",
                              "--trials", "4", "--out", str(out), "--no-progress",
                              *(x for s in SHORT for x in ("--set", s))])  # fmt: skip
    assert res.exit_code == 0, res.output
    with (out / "trials.csv").open() as f:
        header = next(csv.reader(f))
    assert header == ["family", "trial", "constant", "policy:gyro_run"]


def test_judging_refuses_a_missing_policy_and_episodes_too_short_to_judge() -> None:
    with pytest.raises(ConfigError, match=r"--methods: 'policy:/nonexistent/model\.zip'"):
        plan_judging(
            "redundant_gyros", ["gyro_control"], ["constant", "policy:/nonexistent/model.zip"]
        )
    with pytest.raises(ConfigError, match="leaves no judged epoch"):
        plan_judging("redundant_gyros", ["gyro_control"], ["constant", "clock"],
                     overrides=["scenario.duration_s=20"])  # fmt: skip


def test_on_a_shift_family_the_tuned_methods_tune_on_the_family_it_shifts_from() -> None:
    """Judged on ``gyro_shift_noise_levels``, the tuned constant is tuned on the tuning episodes
    of ``gyro_noise_levels`` (what a policy trained there meets), never on the shift itself;
    on any other family, on its own."""
    plan = plan_judging(
        "redundant_gyros", ["gyro_control", "gyro_shift_noise_levels"], ["constant", "clock"],
        trials=2, overrides=SHORT,
    )  # fmt: skip
    assert plan.tuning_configs[0] is None
    assert plan.tuning_configs[1] == load_gyros("gyro_noise_levels", SHORT)
    control, shifted = versus_markdown(plan, []).split("## gyro_shift_noise_levels")
    assert "tuned on `gyro_noise_levels`'s tuning trials" in shifted  # versus.md says so
    assert "tuning trials" not in control
    prob = plan.problem
    shift = plan.configs[1]
    source = plan.tuning_configs[1]
    got = prob.trial_errors(shift, TrialRequest(("constant",), 2, 5_000_000, source))["constant"]
    episodes = prob.simulate(shift, 5_000_000, range(2))
    tuned = {
        id(cfg): np.sqrt(GYRO_METHODS["constant"](shift, episodes, prob.tuning(cfg)))
        for cfg in (source, shift)
    }
    np.testing.assert_allclose(got, tuned[id(source)], rtol=1e-12)
    assert not np.allclose(got, tuned[id(shift)])  # tuned on the shift, another κ


def test_transfer_alignment_shift_families_tune_on_the_mixture_like_the_mixed_twins() -> None:
    """Judged on a shift family, ``kf-tuned`` tunes on the training mixture's scenario: its
    errors are those of ``kf-tuned-mixed`` on the same trials; ``kf`` is untouched."""
    short = ["scenario.duration_s=900", "run.settled_s=300", "adaptive.tuned.trials=2"]
    specs = ["kf", "kf-tuned", "kf-tuned-mixed"]
    plan = plan_judging(
        "transfer_alignment", ["shift_late_snap_random"], specs, trials=2, overrides=short
    )
    assert plan.tuning_configs[0] == PROBLEMS["transfer_alignment"].load_config(
        "mixed_random", short
    )
    request = TrialRequest(tuple(plan.specs), 2, plan.seed, plan.tuning_configs[0])
    errors = plan.problem.trial_errors(plan.configs[0], request)
    np.testing.assert_array_equal(errors["kf-tuned"], errors["kf-tuned-mixed"])
    own = plan.problem.trial_errors(plan.configs[0], TrialRequest(("kf", "kf-tuned"), 2, plan.seed))
    np.testing.assert_array_equal(own["kf"], errors["kf"])
    assert not np.array_equal(own["kf-tuned"], errors["kf-tuned"])  # tuned on the shift itself


def test_a_policy_of_another_action_set_is_refused_before_any_work(
    tmp_path: Path, bare_gyro_policy: str
) -> None:
    """The policies choose among the default 11 κ; a family whose action set has 5 is refused
    by the plan (naming the family, the model and both counts), for either problem."""
    gyro = f"policy:{bare_gyro_policy}"
    plan_judging("redundant_gyros", ["gyro_control"], ["constant", gyro], overrides=SHORT)
    with pytest.raises(ConfigError, match=r"family gyro_control: .*gyro_ppo\.zip.*among 11 "
                       r"actions.*\(environment\.actions\) has 5"):  # fmt: skip
        plan_judging("redundant_gyros", ["gyro_control"], ["constant", gyro],
                     overrides=[*SHORT, "environment.actions.count=5"])  # fmt: skip
    shipped = Path(__file__).resolve().parents[1] / "agents" / "zoo" / "best" / "model.zip"
    ta = ["kf", f"policy:{shipped}"]
    plan_judging("transfer_alignment", ["steady_random"], ta, trials=2)
    with pytest.raises(ConfigError, match=r"family steady_random: .*among 11 actions.*"
                       r"\(adaptive\.actions\) has 5"):  # fmt: skip
        plan_judging("transfer_alignment", ["steady_random"], ta, trials=2,
                     overrides=["adaptive.actions.count=5"])  # fmt: skip
