"""What every command of the command line shares: consoles, the exit-2 error and output checks.

Each estimation problem may add its own command group (a ``typer.Typer`` in
``qkf/<problem>/cli.py``, mounted by :mod:`qkf.cli`); these helpers keep their messages and
exit codes the same as the top-level commands': 0 success, 2 bad input (config, data file,
option), 1 anything else.

``--out`` options are taken as text (``str``), not ``Path``: a ``Path`` turns ``''`` into ``.``
and drops the trailing slash of ``newdir/``, and both must be refused, not reinterpreted.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
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
