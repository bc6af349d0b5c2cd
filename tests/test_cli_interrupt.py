"""Ctrl-C in any command: one line, ``interrupted``, on stderr and exit 130; no traceback (not
Optuna's log of the trial it interrupted either), no half-written output, worker processes
stopped at once. Each test runs ``qkf`` as a user does, in a process group of its own, and
sends SIGINT to the whole group (as a terminal's Ctrl-C does) once the work has started."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(os.name != "posix", reason="process groups and a pty")

READY_ENV = "QKF_TEST_READY"
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def optuna_method(cfg: Any, data: Any) -> Any:
    """A method that runs an Optuna study as the ``-tuned`` methods do, its trial waiting to be
    interrupted (``READY_ENV`` names the file it creates once inside the trial)."""
    import optuna

    from qkf.transfer_alignment.methods.tuned import quiet_optuna

    def objective(trial: optuna.Trial) -> float:
        Path(os.environ[READY_ENV]).touch()
        end = time.monotonic() + 60
        while time.monotonic() < end:
            time.sleep(0.01)
        return 0.0

    with quiet_optuna():
        optuna.create_study().optimize(objective, n_trials=1)
    raise AssertionError("not interrupted")


def _qkf() -> list[str]:
    script = Path(sys.executable).with_name("qkf")  # the console script, as installed
    return [str(script)] if script.is_file() else [sys.executable, "-m", "qkf"]


def _as_from_a_terminal() -> None:
    """In the child before it runs qkf: SIGINT handled and delivered as in a process a shell
    starts. A disposition of "ignore" and a blocked signal survive exec, so a test worker that
    inherited either (from whatever ran in it before) would otherwise pass it on, and the
    Ctrl-C would never arrive."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])


def _interrupt(
    args: list[str], cwd: Path, started: Any, env: dict[str, str] | None = None
) -> tuple[int, str]:
    """Run ``qkf ARGS`` with its stdout on a pty (a terminal: the progress bar is drawn as it
    goes), wait until ``started(stdout so far, without colours)`` holds, then Ctrl-C its
    process group; the exit status and stderr."""
    import pty

    main, sub = pty.openpty()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1", "COLUMNS": "100",
           **(env or {})}  # fmt: skip
    proc = subprocess.Popen(
        [*_qkf(), *args], cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=sub,
        stderr=subprocess.PIPE, start_new_session=True, preexec_fn=_as_from_a_terminal,
    )  # fmt: skip
    os.close(sub)
    shown = bytearray()

    def read() -> None:
        try:
            while chunk := os.read(main, 65536):
                shown.extend(chunk)
        except OSError:  # the pty is closed when the process has gone
            pass

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        end = time.monotonic() + 120  # numba compiles on a first run
        while not started(text := ANSI.sub("", bytes(shown).decode(errors="replace"))):
            assert proc.poll() is None, f"ended before Ctrl-C: {text[-500:]!r}"
            assert time.monotonic() < end, f"not started: {text[-500:]!r}"
            time.sleep(0.1)
        os.killpg(proc.pid, signal.SIGINT)
        sent = time.monotonic()
        _, err = proc.communicate(timeout=60)
        took = time.monotonic() - sent
    finally:  # nothing of the group left running (workers included), whatever happened
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()
        os.close(main)
        reader.join(5)
    # the workers are stopped, not left to finish their queued chunks (that took 45 s)
    assert took < 20, f"exit took {took:.0f} s after Ctrl-C"
    return proc.returncode, err.decode(errors="replace")


@pytest.fixture(scope="module", autouse=True)
def _compiled(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The compiled code these commands run, in numba's cache before the first Ctrl-C: a signal
    reaches Python only between bytecodes, and a first run spends a minute or more inside LLVM
    (a fresh clone), where a Ctrl-C waits for the compilation to end."""
    where = tmp_path_factory.mktemp("warm")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_NUM_THREADS": "1"}
    for i, extra in enumerate(([], ["--workers", "2"])):
        subprocess.run(
            [*_qkf(), "bench", "paper", "--methods", "kf", "--trials", "2", "--quiet",
             "--set", "scenario.duration_s=20", "--out", str(where / f"b{i}"), *extra],
            env=env, check=True, capture_output=True, timeout=600,
        )  # fmt: skip


def _one_line(code: int, err: str) -> None:
    assert code == 130, err
    assert err == "interrupted\n", err


def _hidden(folder: Path) -> list[str]:
    """What an interrupted write could leave: temporary files, staging and .old folders."""
    return [str(p) for p in folder.rglob(".*")]


def test_ctrl_c_in_a_bench_with_worker_processes(tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["bench", "paper", "--methods", "kf", "--trials", "2000", "--workers", "2",
            "--set", "run.chunk_trials=8", "--out", str(out)]  # fmt: skip
    # a trial count above 0 on the bar: the workers are computing
    code, err = _interrupt(args, tmp_path, lambda s: re.search(r"[1-9]\d*/2,?000 trials", s))
    _one_line(code, err)
    assert not out.exists()  # a bench folder appears whole, at the end
    assert _hidden(tmp_path) == []


def test_ctrl_c_in_an_optuna_trial_of_a_study(tmp_path: Path) -> None:
    """Optuna catches the KeyboardInterrupt in a trial and logs it with its traceback before
    raising it again; the study folder keeps only what was finished (resumable)."""
    study = tmp_path / "s.yaml"
    study.write_text(
        f"name: s\nkind: bench\nbase: {ROOT / 'configs' / 'transfer_alignment' / 'paper.yaml'}\n"
        "methods: ['tests.test_cli_interrupt:optuna_method']\ntrials: 2\nseed: 0\n"
        "metric: sf_ppm_final\ncases:\n  - {label: a, set: [scenario.duration_s=20]}\n"
    )
    ready = tmp_path / "ready"
    out = tmp_path / "out"
    code, err = _interrupt(
        ["study", str(study), "--out", str(out), "--quiet"], tmp_path,
        lambda _: ready.exists(), {READY_ENV: str(ready)},
    )  # fmt: skip
    _one_line(code, err)
    assert sorted(p.name for p in out.iterdir()) == ["run.json"]  # no case finished
    assert _hidden(tmp_path) == []
