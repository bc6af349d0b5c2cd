"""``python -m qkf`` and the ``qkf`` console script: the command line (:mod:`qkf.cli`).

The entry point imports the command line inside :func:`main`, so a Ctrl-C while it is still
being imported (numba, scipy, torch for the agents' commands: up to a second) is the same one
line and exit 130 as a Ctrl-C in a command (:func:`qkf.core.cli_support.interruptible`).
"""

from __future__ import annotations

import sys

INTERRUPTED = 130  # 128 + SIGINT (qkf.core.cli_support.INTERRUPTED, not imported: see above)


def main() -> None:
    """Run the ``qkf`` command line."""
    try:
        from qkf.cli import app
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        raise SystemExit(INTERRUPTED) from None
    app(prog_name="qkf")


if __name__ == "__main__":
    main()
