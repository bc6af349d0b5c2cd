"""What every command of the command line shares: consoles, the exit-2 error, output checks and
Ctrl-C.

Each estimation problem may add its own command group (a ``typer.Typer`` in
``qkf/<problem>/cli.py``, mounted by :mod:`qkf.cli`); these helpers keep their messages and
exit codes the same as the top-level commands': 0 success, 2 bad input (config, data file,
option), 130 interrupted (Ctrl-C), 1 anything else.

``--out`` options are taken as text (``str``), not ``Path``: a ``Path`` turns ``''`` into ``.``
and drops the trailing slash of ``newdir/``, and both must be refused, not reinterpreted.
"""

from __future__ import annotations

import logging
import multiprocessing
import signal
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

err = Console(stderr=True)
out = Console()

SetOption = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override a config value: dotted.key=value (YAML value)."),
]
OverwriteOption = Annotated[
    bool,
    typer.Option(
        "--overwrite",
        help="Replace an earlier run of this command in --out (a folder holding anything else "
        "is never replaced).",
    ),
]


NoCacheOption = Annotated[
    bool,
    typer.Option(
        "--no-cache",
        help="Compute every result afresh: neither read nor write the results cache "
        "($QKF_CACHE_DIR/results; also $QKF_NO_CACHE=1). See docs/caching.md.",
    ),
]

BackendOption = Annotated[
    str, typer.Option(help="local (processes on this machine) or ray (Ray tasks).")
]


def backend_options(backend: str, workers: int | None) -> None:
    """Refuse an unknown ``--backend`` or ``--workers`` below 1 (exit 2) before any work."""
    from qkf.core.montecarlo import BACKENDS

    if backend not in BACKENDS:
        raise fail(f"--backend: {backend!r} is not {' or '.join(BACKENDS)}")
    if workers is not None and workers < 1:
        raise fail("--workers must be at least 1")


def fail(msg: str, code: int = 2) -> typer.Exit:
    """Print ``error: msg`` to stderr and return the ``typer.Exit`` to raise (exit 2: bad input)."""
    # soft_wrap: a message must not be broken at the terminal width (file paths, fields)
    err.print(f"[bold red]error:[/] {escape(msg)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)


@contextmanager
def refused(prefix: str = "") -> Iterator[None]:
    """Turn a ``ConfigError`` raised in the block into exit 2 with its message (after
    ``prefix``, e.g. the config file's name)."""
    from qkf.core.config import ConfigError

    try:
        yield
    except ConfigError as exc:
        raise fail(f"{prefix}{exc}") from None


def out_dir(
    raw: str | Path, kind: str, overwrite: bool | None = False, option: str = "--out"
) -> Path:
    """The output folder of a command writing a run of ``kind`` (``run.json``), checked before
    any work (exit 2): see :func:`qkf.core.io.check_output_dir`. ``overwrite`` None: an earlier
    run of the same kind is replaced without being asked (work folders a command owns)."""
    from qkf.core.io import OutputError, check_output_dir

    try:
        return check_output_dir(raw, kind, overwrite)
    except OutputError as exc:
        raise fail(f"{option}: {exc}") from None


def out_file(raw: str | Path, header: str | None = None, option: str = "--out") -> Path:
    """The output file of a command, checked before any work (exit 2): see
    :func:`qkf.core.io.check_output_file`; ``header``: the first line the command writes."""
    from qkf.core.io import OutputError, check_output_file

    try:
        return check_output_file(raw, header)
    except OutputError as exc:
        raise fail(f"{option}: {exc}") from None


def seed_option(seed: int | None) -> None:
    """Refuse a seed outside ``[0, 2**63)`` (numpy's ``SeedSequence`` range used here)."""
    if seed is not None and not 0 <= seed < 2**63:
        raise fail("--seed must be between 0 and 2**63 - 1")


INTERRUPTED = 130
"""Exit status after Ctrl-C: 128 + SIGINT, what a shell reports for a command it interrupted."""


@contextmanager
def interruptible() -> Iterator[None]:
    """Ctrl-C while the block (the whole command line) runs: one line, ``interrupted``, on
    stderr and exit 130, whatever the command was doing.

    The interrupted code still cleans up on its way out (``qkf.core.io`` removes its temporary
    files and staging folders: no half-written output is left), but prints nothing: from the
    first Ctrl-C, logging and warnings are off (Optuna logs the trial it was in, with its
    traceback), and worker processes (``--workers``) are stopped at once instead of finishing
    the chunks queued for them. A second Ctrl-C interrupts that cleanup too. A block that
    finishes successfully all the same keeps its exit status. The block runs as it is outside
    the main thread (signals reach only that one) and where SIGINT is ignored (a background job
    of a script: Ctrl-C is not meant for it).
    """
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    ):
        yield
        return
    hit = False

    def on_ctrl_c(signum: int, frame: FrameType | None) -> None:
        nonlocal hit
        if not hit:
            hit = True
            logging.disable(logging.CRITICAL)
            warnings.simplefilter("ignore")
            for child in multiprocessing.active_children():
                child.terminate()
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_ctrl_c)
    try:
        yield
    except BaseException as exc:
        # typer turns a KeyboardInterrupt into exit 130 (older versions: "Aborted!", exit 1),
        # and the cleanup after a Ctrl-C may fail in its own way (a stopped worker's pipe)
        exited = exc.code if isinstance(exc, SystemExit) else "raised"
        hit = hit or isinstance(exc, KeyboardInterrupt) or exited == INTERRUPTED
        if not hit or exited in (0, None):
            raise
    else:
        return
    finally:
        # None: a handler set outside Python
        signal.signal(signal.SIGINT, signal.SIG_DFL if previous is None else previous)
    err.print("interrupted", highlight=False, markup=False)
    raise SystemExit(INTERRUPTED)
