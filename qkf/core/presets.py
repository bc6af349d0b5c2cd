"""Presets by name: ``qkf bench paper`` as well as ``qkf bench configs/paper.yaml``.

The preset files have one home, the project's ``configs/`` folder. A wheel carries the same
files as ``qkf/presets/`` (``pyproject.toml`` maps the folder into the package), so a name
resolves the same way from a source checkout, an editable install or an installed wheel.
"""

from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]
_CANDIDATES = (_PACKAGE / "presets", _PACKAGE.parent / "configs")


def preset_dir() -> Path:
    """The folder holding the presets (installed copy first, then the source tree)."""
    for folder in _CANDIDATES:
        if folder.is_dir():
            return folder
    raise FileNotFoundError("no preset folder: neither qkf/presets nor configs/ exists")


def preset_names(subdir: str = "") -> list[str]:
    """Names of the presets in ``subdir`` of the preset folder (``studies`` for studies)."""
    try:
        folder = preset_dir() / subdir
    except FileNotFoundError:
        return []
    return sorted(p.stem for p in folder.glob("*.yaml"))


def is_preset_name(value: str | Path) -> bool:
    """A bare name (no folder, no suffix other than ``.yaml``) rather than a path."""
    text = str(value)
    return (
        bool(text) and "/" not in text and "\\" not in text and Path(text).suffix in ("", ".yaml")
    )


def resolve(name_or_path: str | Path, subdir: str = "") -> Path:
    """The file a config argument means.

    An existing path is taken as it is; otherwise a bare name (``thermal_snap`` or
    ``thermal-snap``) is looked up among the presets of ``subdir``. Anything else is returned
    unchanged, so the loader reports it as a missing file.
    """
    path = Path(name_or_path)
    if path.exists() or not is_preset_name(name_or_path):
        return path
    stem = Path(str(name_or_path)).stem.replace("-", "_")
    try:
        candidate = preset_dir() / subdir / f"{stem}.yaml"
    except FileNotFoundError:
        return path
    return candidate if candidate.is_file() else path
