"""Presets by name: ``qkf bench paper`` as well as a path to any YAML file.

The preset files have one home, the project's ``configs/`` folder, one subfolder per estimation
problem (``configs/<problem>/``: ``transfer_alignment``, ``redundant_gyros``, ``sca_fusion``,
``alignment``; ``transfer_alignment/studies``; ``training`` for the agents' training configs).
A wheel carries the same files as ``qkf/presets/`` (``pyproject.toml`` maps the folder into the
package), so a name resolves the same way from a source checkout, an editable install or an
installed wheel. A problem looks names up in its own folder only, so its "no such preset"
lists its own presets.
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel

from qkf.core.config import ConfigError, load_model

_PACKAGE = Path(__file__).resolve().parents[1]
_CANDIDATES = (_PACKAGE / "presets", _PACKAGE.parent / "configs")

M = TypeVar("M", bound=BaseModel)


def preset_dir(folder: str = "") -> Path:
    """The folder holding the presets of ``folder`` (installed copy first, then the source
    tree); ``FileNotFoundError`` if neither exists."""
    for root in _CANDIDATES:
        if root.is_dir():
            return root / folder
    raise FileNotFoundError("no preset folder: neither qkf/presets nor configs/ exists")


def preset_names(folder: str) -> list[str]:
    """Names of the presets in ``folder`` of the preset tree (``transfer_alignment/studies``)."""
    try:
        where = preset_dir(folder)
    except FileNotFoundError:
        return []
    return sorted(p.stem for p in where.glob("*.yaml"))


def is_preset_name(value: str | Path) -> bool:
    """A bare name (no folder, no suffix other than ``.yaml``) rather than a path."""
    text = str(value)
    return (
        bool(text) and "/" not in text and "\\" not in text and Path(text).suffix in ("", ".yaml")
    )


def preset_path(name: str | Path, folder: str) -> Path | None:
    """The preset file a bare name means in ``folder`` (``thermal_snap`` or ``thermal-snap``),
    or None if it names none; never looks at the working directory."""
    if not is_preset_name(name):
        return None
    stem = Path(str(name)).stem.replace("-", "_")
    try:
        candidate = preset_dir(folder) / f"{stem}.yaml"
    except FileNotFoundError:
        return None
    return candidate if candidate.is_file() else None


def resolve(name_or_path: str | Path, folder: str) -> Path:
    """The file a config argument means.

    An existing path is taken as it is; otherwise a bare name is looked up among the presets of
    ``folder``. Anything else is returned unchanged, so the loader reports it as a missing file.
    """
    path = Path(name_or_path)
    if path.exists():
        return path
    return preset_path(name_or_path, folder) or path


def missing(name_or_path: str | Path, folder: str, what: str = "config") -> ConfigError | None:
    """The error for a bare name that is neither a file nor a preset of ``folder`` (listing that
    folder's presets), or None."""
    if Path(name_or_path).exists() or not is_preset_name(name_or_path):
        return None
    if preset_path(name_or_path, folder) is not None:
        return None
    known = ", ".join(preset_names(folder)) or "none"
    return ConfigError(f"{name_or_path}: no such {what} file or preset (presets: {known})")


def load_preset(
    model: type[M],
    name_or_path: str | Path | None,
    folder: str,
    overrides: list[str] | None = None,
    what: str = "configuration",
) -> M:
    """Read and validate a config of ``model`` — a path, or a preset name of ``folder`` — then
    apply ``--set`` overrides (``None``: the model's defaults). The one loader of every problem;
    ``ConfigError`` names the file and the field, or lists the folder's presets."""
    if name_or_path is None:
        return load_model(model, None, overrides, what)
    error = missing(name_or_path, folder)
    if error is not None:
        raise error
    return load_model(model, resolve(name_or_path, folder), overrides, what)
