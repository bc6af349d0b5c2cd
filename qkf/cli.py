"""The command line ``qkf``: the one module that sits above ``qkf``, ``envs`` and ``agents``.

It only mounts the command apps of the estimation problems (``qkf/<problem>/cli.py``:
``crlb``, ``bench``, ``plot``, ``study`` of transfer alignment; the ``gyros`` group; ``fuse``;
``align``), ``judge`` (any problem, through the problem registry) and the agents' apps
(``agents/cli.py``: ``train``, ``evaluate``, ``zoo``). The library
never imports envs or agents; the agents' commands import them when they run (so ``torch`` is
loaded only by the commands that use an agent). Exit codes: 0 success, 2 bad input (config,
data, option), 130 interrupted (Ctrl-C: one line, ``interrupted``, on stderr), 1 anything else.
"""

from __future__ import annotations

import sys
from typing import Annotated, Any

import typer

from agents.cli import app as agents_app
from qkf.alignment.cli import app as alignment_app
from qkf.cache_cli import app as cache_app
from qkf.core.cli_support import interruptible, out
from qkf.judge_cli import app as judge_app
from qkf.redundant_gyros.cli import app as gyros_app
from qkf.sca_fusion.cli import app as fusion_app
from qkf.transfer_alignment.cli import app as transfer_alignment_app


class _CommandLine(typer.Typer):
    """The ``qkf`` app. Called (the console script ``qkf``, ``python -m qkf``), a Ctrl-C in any
    command is one line and exit 130 (:func:`qkf.core.cli_support.interruptible`); a test's
    ``CliRunner`` invokes the commands without it."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        with interruptible():
            return super().__call__(*args, **kwargs)


app = _CommandLine(
    add_completion=False,
    no_args_is_help=True,
    help="qkf: adaptive Kalman filtering gym for in-orbit gyro calibration.",
)


def _show_version(value: bool) -> None:
    if value:
        from qkf import __version__

        out.print(f"qkf {__version__}", highlight=False)
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_show_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """qkf: adaptive Kalman filtering gym for in-orbit gyro calibration."""


# Each problem's commands live in its own package (qkf/<problem>/cli.py, a Typer app); the
# agents' in agents/cli.py. This module only mounts them: a command group (gyros) or, unnamed,
# top-level commands.
app.add_typer(transfer_alignment_app)
app.add_typer(agents_app)
app.add_typer(gyros_app, name="gyros", help="Redundant skewed gyros: FDI and UKF calibration.")
app.add_typer(fusion_app)
app.add_typer(alignment_app)
app.add_typer(cache_app, name="cache")
app.add_typer(judge_app)


def main() -> None:  # pragma: no cover - entry point
    app()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
