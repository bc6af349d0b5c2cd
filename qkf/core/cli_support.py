"""What every command of the command line shares: consoles, the exit-2 error and output checks.

Each estimation problem may add its own command group (a ``typer.Typer`` in
``qkf/<problem>/cli.py``, mounted by :mod:`qkf.cli`); these helpers keep their messages and
exit codes the same as the top-level commands': 0 success, 2 bad input (config, data file,
option), 1 anything else.
"""

from __future__ import annotations

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


def fail(msg: str, code: int = 2) -> typer.Exit:
    """Print ``error: msg`` to stderr and return the ``typer.Exit`` to raise (exit 2: bad input)."""
    # soft_wrap: a message must not be broken at the terminal width (file paths, fields)
    err.print(f"[bold red]error:[/] {escape(msg)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)


def check_out(path: Path, kind: str = "dir") -> None:
    """Refuse an unusable ``--out`` (a file for a folder, a missing parent): exit 2."""
    from qkf.core.io import OutputError, check_output_dir, check_output_file

    try:
        (check_output_dir if kind == "dir" else check_output_file)(path)
    except OutputError as exc:
        raise fail(f"--out: {exc}") from None
