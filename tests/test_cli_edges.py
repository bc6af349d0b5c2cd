"""Rough edges a new user hits on the command line (issue 18): each is exit 2 with one message,
before any work and without a traceback."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qkf import __version__
from qkf.cli import app

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
BEST = ROOT / "agents" / "zoo" / "best"
SHORT = ["--set", "scenario.duration_s=60", "--set", "run.settled_s=20"]


def _refused(args: list[str], *needles: str) -> str:
    res = runner.invoke(app, args)
    text = " ".join(res.output.split())
    assert res.exit_code == 2, res.output
    assert "Traceback" not in text and text.count("error:") == 1, res.output
    for needle in needles:
        assert needle in text, res.output
    return text


@pytest.fixture
def corrupt_model(tmp_path: Path) -> Path:
    """A model.zip that is not one, beside a real training config."""
    folder = tmp_path / "agent"
    folder.mkdir()
    shutil.copy(BEST / "config.yaml", folder / "config.yaml")
    (folder / "model.zip").write_bytes(b"PK\x03\x04 truncated, not a zip archive")
    return folder / "model.zip"


def test_version() -> None:
    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"qkf {__version__}"


@pytest.mark.parametrize(
    ("methods", "needle"),
    [
        ("", "no method given"),
        (" , ", "no method given"),
        ("policy:", "no model path given"),
        (f"policy:{BEST}", "is a directory, not a model file"),
    ],
)
def test_bench_methods_refused(methods: str, needle: str, tmp_path: Path) -> None:
    _refused(["bench", "paper", "--methods", methods, "--out", str(tmp_path / "o"), *SHORT],
             "--methods", needle)  # fmt: skip
    assert not (tmp_path / "o").exists()


def test_corrupt_model_is_refused_up_front(corrupt_model: Path, tmp_path: Path) -> None:
    out = tmp_path / "o"
    _refused(["bench", "paper", "--methods", f"policy:{corrupt_model}", "--out", str(out),
              *SHORT], "not a readable ppo model")  # fmt: skip
    _refused(["evaluate", str(corrupt_model), "--out", str(out), *SHORT],
             "not a readable ppo model")  # fmt: skip
    assert not out.exists()


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--seed", "-1"], "--seed must be between 0 and 2**63 - 1"),
        (["--trials", "0"], "--trials must be between 1"),
    ],
)
def test_evaluate_options_refused(args: list[str], needle: str, tmp_path: Path) -> None:
    _refused(["evaluate", str(BEST / "model.zip"), *args, "--out", str(tmp_path / "o")], needle)
    assert not (tmp_path / "o").exists()


def test_evaluate_a_directory_or_missing_model(tmp_path: Path) -> None:
    _refused(["evaluate", str(BEST)], "is a directory, not a model file")
    _refused(["evaluate", str(tmp_path / "nope.zip")], "no such model file")


@pytest.mark.parametrize(
    ("seeds", "needle"), [("", "an empty list"), (",", "an empty list"), ("1,1", "twice")]
)
def test_zoo_train_seed_lists(seeds: str, needle: str, tmp_path: Path) -> None:
    _refused(["zoo", "train", "ppo_snap_random", "--seeds", seeds, "--work", str(tmp_path / "w")],
             "--seeds", needle)  # fmt: skip
    assert not (tmp_path / "w").exists()


def test_zoo_evaluate_untrained_entry_is_refused(tmp_path: Path) -> None:
    entry = tmp_path / "untrained"
    entry.mkdir()
    (entry / "zoo.yaml").write_text(
        "train: train_ppo_snap_random_v2\nseeds: [0, 1, 2]\n"
        "judge: {scenario: thermal_snap_random}\n"
    )
    _refused(["zoo", "evaluate", str(entry), "--work", str(tmp_path / "w")], "no trained seed")
    assert sorted(p.name for p in entry.iterdir()) == ["zoo.yaml"]
