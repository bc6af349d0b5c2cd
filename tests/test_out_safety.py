"""No command deletes or overwrites a file it did not write, and none fails late on its output
path (issue 18): every command that writes refuses an unusable ``--out`` before any work (exit 2,
one message, nothing written), a folder holding anything but an earlier qkf run of the same kind
is never replaced, and an earlier run is replaced only with ``--overwrite``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.core import io
from qkf.core.io import OutputError, check_output_dir, check_output_file, staged_directory

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "agents" / "zoo" / "best" / "model.zip"
SHORT = ["--set", "scenario.duration_s=60", "--set", "run.settled_s=20"]

# every command that writes a run folder, without its --out (all refuse before any work)
DIR_COMMANDS: dict[str, list[str]] = {
    "bench": ["bench", "paper", "--methods", "kf", "--trials", "2", *SHORT, "--quiet"],
    "evaluate": ["evaluate", str(MODEL), "--trials", "2", *SHORT, "--quiet"],
    "fuse": ["fuse", "sca_acc_fusion", "--quiet"],
    "align": ["align", "alignment_three_sensors"],
    "gyros run": ["gyros", "run", "five_gyros"],
    "gyros bench": ["gyros", "bench", "five_gyros", "--trials", "2", "--quiet"],
    "study": ["study", "matching", "--quiet"],
    "claims": ["study", "paper_claims", "--quiet"],
}
FILE_COMMANDS: dict[str, list[str]] = {
    "crlb": ["crlb", "paper", *SHORT],
    "gyros features": ["gyros", "features", "five_gyros"],
}
# folders a command uses as its workspace (checked for what cannot be used at all)
WORK_COMMANDS: dict[str, list[str]] = {
    "train": ["train", "train_tabular", "--quiet", "--out"],
    "zoo train": ["zoo", "train", "ppo_snap_random", "--quiet", "--work"],
    "zoo evaluate": ["zoo", "evaluate", "ppo_snap_random", "--trials", "2", "--quiet", "--work"],
}


def _listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


@pytest.fixture
def cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A working directory of its own holding a file of the user's."""
    work = tmp_path / "cwd"
    work.mkdir()
    (work / "mine.txt").write_text("the user's own file\n")
    monkeypatch.chdir(work)
    return work


@pytest.mark.parametrize("name", sorted(DIR_COMMANDS))
def test_a_folder_of_the_users_is_refused_and_survives(name: str, cwd: Path) -> None:
    out = cwd / "out"
    out.mkdir()
    (out / "sentinel.txt").write_text("keep me\n")
    before = _listing(cwd)
    res = runner.invoke(app, [*DIR_COMMANDS[name], "--out", str(out), "--overwrite"])
    assert res.exit_code == 2, res.output
    assert "not a qkf run" in res.output and "sentinel.txt" in res.output
    assert (out / "sentinel.txt").read_text() == "keep me\n"
    assert _listing(cwd) == before  # nothing written, no staging or .old folder left


@pytest.mark.parametrize("name", sorted(DIR_COMMANDS))
@pytest.mark.parametrize(
    ("where", "expect"),
    [
        ("", "empty path"),
        (".", "is the working directory"),
        ("..", "holds the working directory"),
        ("mine.txt", "exists and is not a directory"),
        ("/proc/nope/out", "cannot create anything in /proc"),
    ],
)
def test_unusable_out_folder_is_refused_before_any_work(
    name: str, where: str, expect: str, cwd: Path
) -> None:
    before = _listing(cwd.parent)
    res = runner.invoke(app, [*DIR_COMMANDS[name], "--out", where])
    assert res.exit_code == 2, res.output
    assert expect in res.output
    assert res.output.count("error:") == 1
    assert _listing(cwd.parent) == before
    assert (cwd / "mine.txt").is_file()


@pytest.mark.parametrize("name", sorted(WORK_COMMANDS))
@pytest.mark.parametrize(
    ("where", "expect"),
    [
        ("", "empty path"),
        (".", "is the working directory"),
        ("mine.txt", "exists and is not a directory"),
        ("/proc/nope/out", "cannot create anything in /proc"),
    ],
)
def test_unusable_work_folder_is_refused(name: str, where: str, expect: str, cwd: Path) -> None:
    before = _listing(cwd.parent)
    res = runner.invoke(app, [*WORK_COMMANDS[name], where])
    assert res.exit_code == 2, res.output
    assert expect in res.output
    assert _listing(cwd.parent) == before


@pytest.mark.parametrize("name", sorted(FILE_COMMANDS))
@pytest.mark.parametrize(
    ("where", "expect"),
    [
        ("", "empty path"),
        ("newdir/", "names a folder"),
        (".", "is a directory, not a file"),
        ("mine.txt", "is not an earlier output of this command"),
        ("/proc/nope/x.csv", "cannot create anything in /proc"),
    ],
)
def test_unusable_out_file_is_refused_before_any_work(
    name: str, where: str, expect: str, cwd: Path
) -> None:
    before = _listing(cwd)
    res = runner.invoke(app, [*FILE_COMMANDS[name], "--out", where])
    assert res.exit_code == 2, res.output
    assert expect in res.output
    assert _listing(cwd) == before
    assert (cwd / "mine.txt").read_text() == "the user's own file\n"


@pytest.mark.parametrize("name", sorted(FILE_COMMANDS))
def test_an_earlier_output_file_is_replaced(name: str, cwd: Path) -> None:
    for _ in range(2):
        res = runner.invoke(app, [*FILE_COMMANDS[name], "--out", "table.csv"])
        assert res.exit_code == 0, res.output
    assert sorted(os.listdir(cwd)) == ["mine.txt", "table.csv"]


def test_an_earlier_run_is_replaced_only_with_overwrite(cwd: Path) -> None:
    args = ["align", "alignment_three_sensors", "--out", "run"]
    assert runner.invoke(app, args).exit_code == 0
    info = json.loads((cwd / "run" / "run.json").read_text())
    assert info["kind"] == "align"
    assert sorted(info["files"]) == _listing(cwd / "run")  # the run lists what it wrote
    first = (cwd / "run" / "summary.md").stat().st_mtime_ns

    res = runner.invoke(app, args)
    assert res.exit_code == 2 and "--overwrite replaces it" in res.output
    assert (cwd / "run" / "summary.md").stat().st_mtime_ns == first

    assert runner.invoke(app, [*args, "--overwrite"]).exit_code == 0
    (cwd / "run" / "notes.txt").write_text("my notes on that run\n")
    res = runner.invoke(app, [*args, "--overwrite"])
    assert res.exit_code == 2 and "notes.txt" in res.output
    assert (cwd / "run" / "notes.txt").is_file()

    # a run of another kind is not replaced either
    res = runner.invoke(app, ["gyros", "run", "five_gyros", "--out", "run", "--overwrite"])
    assert res.exit_code == 2 and "holds a qkf align run, not a gyros-run run" in res.output
    assert _listing(cwd) == sorted(["mine.txt", "run", *(f"run/{f}" for f in info["files"]),
                                    "run/notes.txt"])  # fmt: skip


def test_bench_overwrite_replaces_its_own_run(cwd: Path) -> None:
    args = [*DIR_COMMANDS["bench"], "--out", "b"]
    assert runner.invoke(app, args).exit_code == 0
    assert runner.invoke(app, args).exit_code == 2
    res = runner.invoke(app, [*args, "--overwrite"])
    assert res.exit_code == 0, res.output
    assert sorted(os.listdir(cwd)) == ["b", "mine.txt"]


def test_protected_folders(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    home, project = tmp_path / "home", tmp_path / "project"
    for folder in (home, project):
        folder.mkdir()
    (project / "pyproject.toml").write_text("")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setattr(io, "_PROJECT_ROOT", project)
    monkeypatch.chdir(tmp_path)
    for path, what in [(home, "home directory"), (project, "project root")]:
        with pytest.raises(OutputError, match=what):
            check_output_dir(path, "bench", True)
        res = runner.invoke(app, ["align", "alignment_three_sensors", "--out", str(path)])
        assert res.exit_code == 2 and what in res.output
    with pytest.raises(OutputError, match="holds the working directory"):
        check_output_dir("/", "bench", True)
    assert sorted(os.listdir(project)) == ["pyproject.toml"]


def test_swap_never_replaces_a_folder_that_gained_foreign_files(tmp_path: Path) -> None:
    """The check is repeated at the swap: a file put into --out during the run survives, and
    the finished run is kept beside it."""
    out = tmp_path / "out"
    with pytest.raises(OutputError, match="new results are in"):
        with staged_directory(out) as stage:
            (stage / "run.json").write_text(json.dumps({"kind": "bench", "config": {}}))
            (stage / "rms.csv").write_text("x\n")
            out.mkdir()
            (out / "late.txt").write_text("written by the user during the run\n")
    assert (out / "late.txt").is_file()
    kept = [p for p in tmp_path.iterdir() if p.name.startswith("out.new-")]
    assert len(kept) == 1 and (kept[0] / "out" / "rms.csv").is_file()


def test_staged_directory_without_manifest_replaces_only_an_empty_folder(tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    with staged_directory(out) as stage:
        (stage / "a.csv").write_text("1\n")
    assert os.listdir(out) == ["a.csv"]
    with pytest.raises(OutputError, match="not a qkf run"):
        with staged_directory(out) as stage:
            (stage / "b.csv").write_text("2\n")
    assert os.listdir(out) == ["a.csv"]


def test_check_output_file_replaces_only_the_same_table(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    path.write_text("t_s,a\n1,2\n")
    assert check_output_file(path, "t_s,a") == path
    with pytest.raises(OutputError, match="not an earlier output"):
        check_output_file(path, "t_s,b")


def test_old_run_without_file_list_is_not_replaced(tmp_path: Path) -> None:
    out = tmp_path / "old"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"kind": "bench", "config": {}}))
    (out / "rms.csv").write_text("x\n")
    with pytest.raises(OutputError, match="before runs listed their files"):
        check_output_dir(out, "bench", True)
