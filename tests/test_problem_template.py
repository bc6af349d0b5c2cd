"""One shape for every problem (docs/architecture.md, "Problem shape").

A fifth problem built by the recipe (tests/example_problem/toy_estimation) mounts on a Typer app
as qkf/cli.py mounts the real ones, gives the same numbers in this process and in a process
pool, lists only its own presets when a name is unknown, and its filter's NEES lies in its χ²
band. Each real problem's "no such preset" lists its own preset folder, and no other's.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from qkf.core import presets
from tests.example_problem.toy_estimation.benchmark import run_bench
from tests.example_problem.toy_estimation.cli import app as toy_app
from tests.example_problem.toy_estimation.config import PRESETS, load_config

ROOT = Path(__file__).resolve().parents[1]
TOY_PRESETS = ROOT / "tests" / "example_problem" / "configs"
runner = CliRunner()


def _root_app() -> typer.Typer:
    """A top-level command line that mounts the toy problem's app, as qkf/cli.py mounts gyros."""
    root = typer.Typer(add_completion=False, no_args_is_help=True)

    @root.callback()
    def _options() -> None:
        """The test's command line."""

    root.add_typer(toy_app, name="toy", help="Toy: a scalar random walk.")
    return root


@pytest.fixture
def preset_tree(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A preset tree (the role of configs/) holding the toy's folder beside another problem's,
    as the toy's presets would sit in configs/toy_estimation/ if it lived in qkf/."""
    tree = tmp_path / "configs"
    shutil.copytree(TOY_PRESETS, tree)
    toy = tree / PRESETS
    short = (toy / "toy_walk.yaml").read_text().replace("duration_s: 100", "duration_s: 20")
    (toy / "toy_short.yaml").write_text(short)
    (tree / "other_problem").mkdir()
    (tree / "other_problem" / "not_mine.yaml").write_text("name: not-mine\n")
    monkeypatch.setattr(presets, "_CANDIDATES", (tree,))
    return tree


def _bench(out: Path, *extra: str) -> Path:
    args = ["toy", "bench", "toy_walk", "--trials", "40", "--seed", "1", "--quiet", *extra]
    res = runner.invoke(_root_app(), [*args, "--set", "bench.chunk_trials=7", "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out


def test_bench_in_process_and_in_a_pool_agree(preset_tree: Path, tmp_path: Path) -> None:
    here = _bench(tmp_path / "here")
    pool = _bench(tmp_path / "pool", "--workers", "2")
    assert (here / "rms.csv").read_bytes() == (pool / "rms.csv").read_bytes()
    info = json.loads((pool / "run.json").read_text())
    assert (info["kind"], info["backend"], info["workers"]) == ("toy-bench", "local", 2)
    assert sorted(info["files"]) == ["rms.csv", "run.json", "summary.md"]
    header = (here / "rms.csv").read_text().splitlines()[0]
    assert header == "t_s,rms_u,sd_u,nees,band_lo,band_hi"


def test_no_such_preset_lists_only_its_own(preset_tree: Path, tmp_path: Path) -> None:
    res = runner.invoke(_root_app(), ["toy", "bench", "nope", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2
    assert "nope: no such config file or preset (presets: toy_short, toy_walk)" in res.output
    assert "not_mine" not in res.output
    assert not (tmp_path / "o").exists()


def test_bad_option_exits_2_before_any_output(preset_tree: Path, tmp_path: Path) -> None:
    res = runner.invoke(
        _root_app(), ["toy", "bench", "toy_walk", "--workers", "0", "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 2 and "--workers must be at least 1" in res.output
    assert not (tmp_path / "o").exists()


def test_nees_lies_in_its_chi2_band() -> None:
    # a consistent filter: each epoch's trial-averaged NEES is inside its 99 % band with
    # probability 0.99; the epochs are correlated, so the fraction varies more than binomially
    # (0.95 to 1 over seeds 0-29 at 400 trials), hence the margin
    cfg = load_config(TOY_PRESETS / PRESETS / "toy_walk.yaml")
    res = run_bench(cfg, trials=400, seed=0)
    assert res.in_band >= 0.9, res.in_band
    assert abs(float(res.nees.mean()) - 1.0) < 0.1
    # and the check has power: a filter that trusts its readings 5× too much is caught
    wrong = load_config(TOY_PRESETS / PRESETS / "toy_walk.yaml", ["walk.assumed_noise_u=0.2"])
    assert run_bench(wrong, trials=400, seed=0).in_band < 0.2


# Each real problem's commands, with an unknown preset name: the list in the message is exactly
# that problem's preset folder (configs/<problem>/).
COMMANDS = {
    "transfer_alignment": ["bench", "nope"],
    "redundant_gyros": ["gyros", "run", "nope"],
    "sca_fusion": ["fuse", "nope"],
    "alignment": ["align", "nope", "--data", "data.csv"],
    "training": ["train", "nope"],
}


@pytest.mark.parametrize("folder", sorted(COMMANDS))
def test_each_problem_lists_its_own_presets(folder: str, tmp_path: Path) -> None:
    from qkf.cli import app

    res = runner.invoke(app, [*COMMANDS[folder], "--out", str(tmp_path / "out")])
    assert res.exit_code == 2, res.output
    flat = " ".join(res.output.split())
    found = re.search(r"nope: no such [\w ]+ or preset \(presets: ([^)]*)\)", flat)
    assert found is not None, flat
    listed = [name.strip() for name in found.group(1).split(",")]
    assert listed == presets.preset_names(folder)
    assert listed == sorted(p.stem for p in (ROOT / "configs" / folder).glob("*.yaml"))
    assert list(tmp_path.iterdir()) == []
