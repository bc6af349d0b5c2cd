"""The --out of a study (and of a sweep) that already holds something: the refusal says what is
in the way and suggests only a flag that then works.

* an earlier qkf study: ``--resume finishes it, --overwrite replaces it``, and both do;
* files qkf did not write (alone or beside an earlier study, at the top or in a case folder):
  refused whatever the flags (exit 2, before any work, nothing written or removed); the message
  names such a file and suggests another --out or emptying the folder, never a flag;
* a qkf run of another kind: refused, another --out suggested;
* a file qkf did not write that ``--overwrite`` would have to remove (a hidden one): only
  ``--resume`` is suggested.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from qkf.cli import app
from tests.test_run_output import _refused

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "configs" / "transfer_alignment" / "paper.yaml"
FLAGS: tuple[list[str], ...] = ([], ["--resume"], ["--overwrite"])


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    return {
        p.relative_to(folder).as_posix(): None if p.is_dir() else p.read_bytes()
        for p in folder.rglob("*")
    }


def _no_flag_suggested(message: str) -> None:
    assert "--resume" not in message and "--overwrite" not in message, message


def _earlier_study(tmp_path: Path) -> tuple[list[str], Path]:
    """A finished one-case study (a CRLB study: a second or two) in ``tmp_path/out``; the
    arguments that ran it."""
    study = tmp_path / "tiny.yaml"
    study.write_text(
        f"name: tiny\nkind: crlb\nbase: {PAPER}\nmetric: sf_ppm_final\n"
        "cases:\n  - {label: a, set: [scenario.duration_s=20]}\n"
    )
    out = tmp_path / "out"
    args = ["study", str(study), "--out", str(out), "--quiet"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    return args, out


def test_a_folder_of_the_users_is_refused_whatever_the_flags(tmp_path: Path) -> None:
    """The reported case: ``qkf study matching --out DIR``, DIR holding a file of the user's."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("the user's own\n")
    before = _snapshot(tmp_path)
    for flags in FLAGS:
        res = runner.invoke(app, ["study", "matching", "--out", str(out), "--quiet", *flags])
        message = _refused(
            res, "not a qkf run (notes.txt)", "choose another --out or empty the folder"
        )
        _no_flag_suggested(message)
        assert _snapshot(tmp_path) == before, flags


def test_an_earlier_study_suggests_resume_and_overwrite_and_both_work(tmp_path: Path) -> None:
    args, out = _earlier_study(tmp_path)
    _refused(
        runner.invoke(app, args),
        "holds an earlier qkf study run; --resume finishes it, --overwrite replaces it",
    )
    for flag in ("--resume", "--overwrite"):
        res = runner.invoke(app, [*args, flag])
        assert res.exit_code == 0, (flag, res.output)
    assert sorted(p.name for p in out.iterdir()) == ["a", "run.json", "study.csv", "study.png"]
    assert not [p for p in tmp_path.rglob(".*")]  # no staging or .old folder left


@pytest.mark.parametrize("where", ["notes.txt", "a/notes.txt", "more/notes.txt"])
def test_an_earlier_study_with_a_file_of_the_users_is_refused(tmp_path: Path, where: str) -> None:
    """--resume would remove a stale case folder and --overwrite the whole folder: neither is
    offered, and neither runs."""
    args, out = _earlier_study(tmp_path)
    (out / where).parent.mkdir(exist_ok=True)
    (out / where).write_text("the user's own\n")
    before = _snapshot(tmp_path)
    for flags in FLAGS:
        message = _refused(
            runner.invoke(app, [*args, *flags]),
            f"holds files qkf did not write beside its earlier study run ({where})",
            "move them out of the folder or choose another --out",
        )
        _no_flag_suggested(message)
        assert _snapshot(tmp_path) == before, flags


def test_a_run_of_another_kind_is_refused(tmp_path: Path) -> None:
    """A study folder as the --out of a sweep (qkf bench on a sweep config)."""
    _, out = _earlier_study(tmp_path)
    before = _snapshot(tmp_path)
    sweep = ["bench", "noise_mismatch", "--methods", "kf", "--trials", "2", "--quiet",
             "--set", "scenario.duration_s=20", "--set", "sweep.values=[1]",
             "--out", str(out)]  # fmt: skip
    for flags in FLAGS:
        message = _refused(
            runner.invoke(app, [*sweep, *flags]),
            "holds a qkf study run, not a sweep run; choose another --out",
        )
        _no_flag_suggested(message)
    assert _snapshot(tmp_path) == before


def test_only_the_flag_that_works_is_suggested(tmp_path: Path) -> None:
    """A hidden file of the user's beside an earlier study: resuming leaves it alone, replacing
    the folder would remove it."""
    args, out = _earlier_study(tmp_path)
    (out / ".notes").write_text("the user's own\n")
    message = _refused(runner.invoke(app, args), "holds an earlier qkf study run; --resume")
    assert "--overwrite" not in message
    _refused(runner.invoke(app, [*args, "--overwrite"]), ".notes")
    res = runner.invoke(app, [*args, "--resume"])
    assert res.exit_code == 0, res.output
    assert (out / ".notes").read_text() == "the user's own\n"
