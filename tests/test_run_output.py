"""Every command fails early and cleanly, and leaves exactly one complete, self-describing run:
bad input (exit 2, one message, nothing written), unusable --out, stale files, file modes,
run.json and --from-manifest, qkf plot, and resumable sweeps and studies."""

from __future__ import annotations

import csv
import json
import os
import stat
from pathlib import Path

import pytest
from typer.testing import CliRunner

from qkf.cli import app
from qkf.transfer_alignment.methods import METHODS

runner = CliRunner()
SHORT = ["--set", "scenario.duration_s=200", "--set", "run.chunk_trials=2"]


def _bench(out: Path, *extra: str, config: str = "paper") -> object:
    return runner.invoke(
        app, ["bench", config, "--trials", "3", "--seed", "1", "--out", str(out), "--quiet",
              *SHORT, *extra],
    )  # fmt: skip


def _refused(result: object, *needles: str) -> str:
    """The one error line of a refusal (exit 2), which holds every needle."""
    out = result.output  # type: ignore[attr-defined]
    assert result.exit_code == 2, out  # type: ignore[attr-defined]
    assert "Traceback" not in out and out.count("error:") == 1, out
    for needle in needles:
        assert needle in out, out
    return out


def test_rerun_leaves_no_stale_file_and_modes_follow_the_umask(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert _bench(out, "--methods", "kf,qkf").exit_code == 0
    assert (out / "kappa.csv").is_file()
    old = os.umask(0o027)
    try:
        assert _bench(out, "--methods", "kf", "--overwrite").exit_code == 0
    finally:
        os.umask(old)
    names = {p.name for p in out.iterdir()}
    assert "kappa.csv" not in names and "kappa.png" not in names  # qkf is not in this run
    assert {"rms.csv", "summary.csv", "run.json", "crlb.csv"} <= names
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging left
    for p in out.iterdir():
        assert stat.S_IMODE(p.stat().st_mode) == 0o640, p
    assert stat.S_IMODE(out.stat().st_mode) == 0o750


def test_run_json_describes_the_run_and_reproduces_it(tmp_path: Path) -> None:
    assert _bench(tmp_path / "a", "--methods", "kf,nominal=kf").exit_code == 0
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert info["kind"] == "bench" and info["trials"] == 3 and info["seed"] == 1
    assert info["backend"] == "local"
    assert [m["spec"] for m in info["methods"]] == ["kf", "nominal=kf"]
    assert info["config"]["scenario"]["duration_s"] == 200  # after the overrides
    libs = info["environment"]["libraries"]
    assert set(libs) == {"numpy", "numba", "scipy", "gymnasium", "stable-baselines3", "torch"}
    assert info["environment"]["qkf"]
    with (tmp_path / "a" / "summary.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["diverged"] for r in rows] == ["0", "0"]
    result = runner.invoke(
        app, ["bench", "--from-manifest", str(tmp_path / "a" / "run.json"), "--out",
              str(tmp_path / "b"), "--quiet"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (tmp_path / "a" / "rms.csv").read_bytes() == (tmp_path / "b" / "rms.csv").read_bytes()


@pytest.mark.figures
def test_plot_redraws_every_figure_from_the_files(tmp_path: Path) -> None:
    out = tmp_path / "run"
    assert _bench(out, "--methods", "kf,qkf").exit_code == 0
    before = {p.name: p.read_bytes() for p in out.glob("*.png")}
    assert set(before) == {"rms_groups.png", "rms_states.png", "kappa.png", "nees.png"}
    for p in out.glob("*.png"):
        p.unlink()
    result = runner.invoke(app, ["plot", str(out)])
    assert result.exit_code == 0, result.output
    after = {p.name: p.read_bytes() for p in out.glob("*.png")}
    assert set(after) == set(before)
    assert all(b[:4] == b"\x89PNG" for b in after.values())
    _refused(runner.invoke(app, ["plot", str(tmp_path / "nothing")]), "no such folder")


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--methods", "a=kf,a=imm"], ["given twice"]),
        (["--methods", "policy:/nonexistent/model.zip"], ["no such model file"]),
        (["--methods", "nosuch"], ["unknown method 'nosuch'"]),
        (["--trials", "0"], ["--trials"]),
    ],
)
def test_bad_bench_options_are_refused(tmp_path: Path, args: list[str], needles: list[str]) -> None:
    _refused(_bench(tmp_path / "out", *args), *needles)
    assert not (tmp_path / "out").exists()


def test_policy_without_its_training_config(tmp_path: Path) -> None:
    model = tmp_path / "agent" / "model.npz"
    model.parent.mkdir()
    model.write_bytes(b"not read")
    _refused(_bench(tmp_path / "out", "--methods", f"policy:{model}"), "no config.yaml beside")


def test_an_existing_file_as_out_is_refused_before_any_work(tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.write_text("mine")
    _refused(_bench(target), "not a directory")
    assert target.read_text() == "mine"
    result = runner.invoke(app, ["crlb", "paper", "--out", str(tmp_path), *SHORT])
    _refused(result, "is a directory")


@pytest.mark.parametrize(
    ("content", "needle"),
    [("", "empty config file"), ("# only a comment\n", "empty config file"),
     ("- 1\n- 2\n", "top level must be a mapping"), ("a: [1\n", "not valid YAML")],
)  # fmt: skip
def test_bad_config_files(tmp_path: Path, content: str, needle: str) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(content)
    _refused(_bench(tmp_path / "out", config=str(path)), str(path), needle)
    assert not (tmp_path / "out").exists()


def test_a_directory_or_unknown_name_as_config(tmp_path: Path) -> None:
    _refused(_bench(tmp_path / "o", config=str(tmp_path)), "is a directory, not a config")
    _refused(_bench(tmp_path / "o", config="no_such_preset"), "no such config file or preset")


def test_matching_option_is_checked_itself(tmp_path: Path) -> None:
    result = runner.invoke(app, ["crlb", "paper", "--matching", "nosuch", "--out",
                                 str(tmp_path / "c.csv")])  # fmt: skip
    _refused(result, "--matching", "'nosuch'")
    assert "--set" not in result.output


def _study(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "s.yaml"
    base = Path(__file__).resolve().parents[1] / "configs" / "transfer_alignment" / "paper.yaml"
    path.write_text(f"name: s\nbase: {base}\ntrials: 2\n" + body)
    return path


def test_bad_study_names_the_study_and_the_case(tmp_path: Path) -> None:
    path = _study(tmp_path, "cases:\n  - {label: ok, set: []}\n"
                            "  - {label: broken, set: [scenario.dt_s=-1]}\n")  # fmt: skip
    _refused(runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "o")]),
             str(path), "cases.1 (broken)", "scenario.dt_s")  # fmt: skip
    path = _study(tmp_path, "methods: [kf, nosuch]\ncases:\n  - {label: a, set: []}\n")
    _refused(runner.invoke(app, ["study", str(path), "--out", str(tmp_path / "o")]),
             "methods", "unknown method 'nosuch'")  # fmt: skip
    assert not (tmp_path / "o").exists()


FAIL_FLAG = {"path": ""}


def kf_failing_at_10s(cfg, data):  # type: ignore[no-untyped-def]
    """The KF, but it fails for a 10-s run while the flag file exists (an interruption)."""
    if cfg.scenario.duration_s == 10 and Path(os.environ["QKF_TEST_FAIL_FLAG"]).exists():
        raise RuntimeError("interrupted")
    return METHODS["kf"](cfg, data)


@pytest.mark.slow  # three study runs (failed, refused, resumed)
def test_an_interrupted_study_resumes_without_recomputing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    flag = tmp_path / "fail"
    flag.write_text("1")
    monkeypatch.setenv("QKF_TEST_FAIL_FLAG", str(flag))
    path = _study(
        tmp_path,
        "methods: ['tests.test_run_output:kf_failing_at_10s']\ncases:\n"
        "  - {label: five, set: [scenario.duration_s=5]}\n"
        "  - {label: ten, set: [scenario.duration_s=10]}\n",
    )
    out = tmp_path / "o"
    first = runner.invoke(app, ["study", str(path), "--out", str(out), "--quiet"])
    assert first.exit_code != 0
    assert (out / "five" / "run.json").is_file() and not (out / "ten").exists()
    stamp = (out / "five" / "run.json").stat().st_mtime_ns
    _refused(runner.invoke(app, ["study", str(path), "--out", str(out), "--quiet"]),
             "--resume")  # fmt: skip
    flag.unlink()
    again = runner.invoke(app, ["study", str(path), "--out", str(out), "--quiet", "--resume"])
    assert again.exit_code == 0, again.output
    assert "five: finished earlier, kept" in again.output and "ten: done" in again.output
    assert (out / "five" / "run.json").stat().st_mtime_ns == stamp
    with (out / "study.csv").open() as f:
        assert [r["case"] for r in csv.DictReader(f)] == ["five", "ten"]
    over = runner.invoke(app, ["study", str(path), "--out", str(out), "--quiet", "--overwrite"])
    assert over.exit_code == 0 and (out / "five" / "run.json").stat().st_mtime_ns != stamp


def test_sweep_resume(tmp_path: Path) -> None:
    out = tmp_path / "sw"
    args = ["bench", "noise_mismatch", "--methods", "kf", "--trials", "2", "--out", str(out),
            "--quiet", "--set", "scenario.duration_s=20",
            "--set", "sweep.values=[1, 10]"]  # fmt: skip
    assert runner.invoke(app, args).exit_code == 0
    stamp = (out / "attitude_sigma_arcsec=1" / "run.json").stat().st_mtime_ns
    _refused(runner.invoke(app, args), "--resume")
    again = runner.invoke(app, [*args, "--resume"])
    assert again.exit_code == 0 and again.output.count("(finished earlier)") == 2
    assert (out / "attitude_sigma_arcsec=1" / "run.json").stat().st_mtime_ns == stamp
    info = json.loads((out / "attitude_sigma_arcsec=1" / "run.json").read_text())
    assert info["config"]["sweep"] is None  # the case alone, rerunnable from its manifest
