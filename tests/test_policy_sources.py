"""``policy:PATH`` for a model trained anywhere (issue 32 item 4): an RL Zoo3 run read from its
own records, a bare Stable-Baselines3 zip with the environment named, and spaces that do not
fit refused before any work with both shapes."""

from __future__ import annotations

import shutil
from collections import OrderedDict
from pathlib import Path

import pytest
import yaml
from conftest import ROOT
from typer.testing import CliRunner

from agents.policy import Policy
from agents.policy_sources import policy_config, split_spec
from qkf.cli import app
from qkf.core.config import ConfigError

BEST = ROOT / "agents" / "zoo" / "best"
ENV = "qkf/TransferAlignment-v3"
SHORT = ["--trials", "2", "--quiet", "--set", "scenario.duration_s=300",
         "--set", "run.settled_s=100"]  # fmt: skip


def _rl_zoo3_run(root: Path) -> Path:
    """The shipped policy laid out as RL Zoo3 saves a run (``logs/ppo/ENV_1/ENV.zip`` and
    ``ENV_1/ENV/{args,config}.yml``, OrderedDicts as RL Zoo3 dumps them)."""
    trained = yaml.safe_load((BEST / "config.yaml").read_text())
    run = root / "logs" / "ppo" / "qkf-TransferAlignment-v3_1"
    (run / "qkf-TransferAlignment-v3").mkdir(parents=True)
    shutil.copy(BEST / "model.zip", run / "qkf-TransferAlignment-v3.zip")
    kwargs = {k: trained[k] for k in ("scenario", "action_type", "reward", "period_s")}
    args = OrderedDict(
        [("algo", "ppo"), ("env", ENV), ("env_kwargs", None), ("gym_packages", ["envs"]),
         ("seed", trained["seed"])]
    )  # fmt: skip
    config = OrderedDict(
        [("env_kwargs", kwargs), ("frame_stack", trained["frame_stack"]), ("n_envs", 16),
         ("policy", "MlpPolicy")]
    )  # fmt: skip
    (run / "qkf-TransferAlignment-v3" / "args.yml").write_text(yaml.dump(args))
    (run / "qkf-TransferAlignment-v3" / "config.yml").write_text(yaml.dump(config))
    return run / "qkf-TransferAlignment-v3.zip"


def _bench(tmp_path: Path, name: str, spec: str) -> bytes:
    out = tmp_path / "runs" / name
    result = CliRunner().invoke(
        app, ["bench", "paper", "--methods", f"p={spec}", *SHORT, "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    return (out / "trials.csv").read_bytes()


def test_split_spec() -> None:
    assert split_spec(f"a/model.zip@{ENV}") == ("a/model.zip", ENV)
    assert split_spec("a/model.zip") == ("a/model.zip", None)
    assert split_spec("me@host/model.zip") == ("me@host/model.zip", None)  # '@' in a path


def test_rl_zoo3_and_bare_zips_read_the_settings_qkf_train_wrote(tmp_path: Path) -> None:
    _, want = policy_config(str(BEST / "model.zip"))
    zoo = _rl_zoo3_run(tmp_path)
    _, got = policy_config(str(zoo))
    fields = ("agent", "env", "action_type", "period_s", "frame_stack", "scenario", "reward")
    assert [getattr(got, f) for f in fields] == [getattr(want, f) for f in fields]
    bare = tmp_path / "bare" / "model.zip"
    bare.parent.mkdir()
    shutil.copy(BEST / "model.zip", bare)
    _, got = policy_config(f"{bare}@{ENV}")
    fields = ("agent", "env", "action_type", "period_s", "frame_stack")
    assert [getattr(got, f) for f in fields] == [getattr(want, f) for f in fields]
    with pytest.raises(FileNotFoundError, match=r"no config\.yaml beside the model.*@ENV_ID"):
        policy_config(str(bare))


@pytest.mark.slow
def test_the_three_kinds_judge_the_same_policy_alike(tmp_path: Path) -> None:
    zoo = _rl_zoo3_run(tmp_path)
    bare = tmp_path / "bare" / "model.zip"
    bare.parent.mkdir()
    shutil.copy(BEST / "model.zip", bare)
    shipped = _bench(tmp_path, "shipped", f"policy:{BEST / 'model.zip'}")
    assert _bench(tmp_path, "zoo", f"policy:{zoo}") == shipped
    assert _bench(tmp_path, "bare", f"policy:{bare}@{ENV}") == shipped


def test_spaces_that_do_not_fit_are_refused_with_both_shapes(tmp_path: Path) -> None:
    bare = tmp_path / "model.zip"
    shutil.copy(BEST / "model.zip", bare)
    with pytest.raises(ConfigError, match=r"shape \[60\], but qkf/TransferAlignment-v2 gives 13"):
        Policy(f"{bare}@qkf/TransferAlignment-v2")
    out = tmp_path / "out"
    result = CliRunner().invoke(
        app,
        ["bench", "paper", "--methods", f"policy:{bare}@qkf/TransferAlignment-v2", *SHORT,
         "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 2 and "[60]" in result.output and "13" in result.output
    assert not out.exists()
    # a config with another action set than the policy's 11 actions: refused before any work
    result = CliRunner().invoke(
        app,
        ["bench", "paper", "--methods", f"policy:{bare}@{ENV}", *SHORT,
         "--set", "adaptive.actions.count=5", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 2 and not out.exists()
    assert "chooses among 11 actions" in result.output and "has 5" in result.output
