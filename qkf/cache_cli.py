"""``qkf cache info|clear``: the caches under ``$QKF_CACHE_DIR`` (docs/caching.md)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated

import typer

from qkf.core.cli_support import out
from qkf.core.results_cache import ResultsCache, cache_root

app = typer.Typer(no_args_is_help=True, help="The results and tuning caches ($QKF_CACHE_DIR).")

TUNING_FILE = re.compile(r"^[A-Za-z0-9_.+-]+-[0-9a-f]{16}\.json$")
"""A tuning-cache file (methods/tuned.py: ``<method>-<16 hex digits of the key>.json``)."""


def _tuning_files() -> list[Path]:
    folder = cache_root() / "tuning"
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.is_file() and TUNING_FILE.match(p.name))


def _size(paths: list[Path]) -> str:
    total = sum(p.stat().st_size for p in paths if p.exists())
    return f"{total / 1e6:.1f} MB" if total >= 1e5 else f"{total / 1e3:.1f} kB"


@app.command()
def info() -> None:
    """Where the caches are and what they hold."""
    results = ResultsCache().entries()
    tuning = _tuning_files()
    out.print(f"cache: {cache_root()}", soft_wrap=True, markup=False)
    out.print(f"  results: {len(results)} entries, {_size(results)} (method results per chunk)")
    out.print(f"  tuning: {len(tuning)} entries, {_size(tuning)} (tuned settings per scenario)")


@app.command()
def clear(
    tuning: Annotated[
        bool, typer.Option(help="Also remove the tuned settings (they take minutes to redo).")
    ] = False,
) -> None:
    """Remove the cached method results (and, with --tuning, the tuned settings). Only files
    the caches wrote are removed."""
    removed = ResultsCache().clear()
    out.print(f"removed {removed} results entries")
    if tuning:
        files = _tuning_files()
        for path in files:
            path.unlink(missing_ok=True)
        out.print(f"removed {len(files)} tuning entries")
