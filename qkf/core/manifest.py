"""``run.json``: what a run was, so that it can be read, cited and reproduced.

Every command that writes results writes a manifest beside them: the resolved configuration
(after presets and ``--set`` overrides), the exact command line, the seed, trial count and
backend, the package version, the git commit when run from a checkout, and the versions of the
numerical libraries. ``qkf bench --from-manifest run.json`` reruns it.
"""

from __future__ import annotations

import json
import platform
import subprocess
import sys
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from qkf.core.config import ConfigError
from qkf.core.io import atomic_write_text

MANIFEST = "run.json"
LIBRARIES = ("numpy", "numba", "scipy", "gymnasium", "stable-baselines3", "torch")
"""Distributions whose versions a manifest records (read from metadata: nothing is imported)."""

_ROOT = Path(__file__).resolve().parents[2]


def _version(dist: str) -> str | None:
    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def git_commit(root: Path = _ROOT) -> dict[str, Any] | None:
    """The checkout's commit and whether it has uncommitted changes; None outside a checkout."""
    if not (root / ".git").exists():
        return None
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": head, "dirty": bool(dirty)}


def environment() -> dict[str, Any]:
    """Package, interpreter and library versions, and the git commit if any."""
    return {
        "qkf": _version("qkf"),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "libraries": {name: _version(name) for name in LIBRARIES},
        "git": git_commit(),
    }


def manifest(
    kind: str, config: dict[str, Any], command: list[str] | None = None, **run: Any
) -> dict[str, Any]:
    """A manifest: ``kind`` (bench, crlb, …), the resolved config, the run's own fields."""
    return {
        "kind": kind,
        "command": list(sys.argv if command is None else command),
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds"),
        **run,
        "config": config,
        "environment": environment(),
    }


def write_manifest(folder: str | Path, data: dict[str, Any]) -> Path:
    """Write ``run.json`` into ``folder`` (atomically)."""
    path = Path(folder) / MANIFEST
    atomic_write_text(path, json.dumps(data, indent=2, ensure_ascii=False) + "\n")
    return path


def read_manifest(path: str | Path, kind: str | None = None) -> dict[str, Any]:
    """Read a manifest (a ``run.json`` file or a folder holding one); ``ConfigError`` if it
    cannot be used."""
    path = Path(path)
    if path.is_dir():
        path = path / MANIFEST
    if not path.is_file():
        raise ConfigError(f"{path}: no such manifest")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not a valid manifest: {exc}") from None
    if not isinstance(data, dict) or "config" not in data or "kind" not in data:
        raise ConfigError(f"{path}: not a qkf manifest (no kind or config)")
    if kind is not None and data["kind"] != kind:
        raise ConfigError(f"{path}: a manifest of a {data['kind']} run, not of a {kind} run")
    return data
