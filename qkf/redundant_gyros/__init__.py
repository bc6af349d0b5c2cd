"""Redundant skewed gyros: fault detection and isolation (three-cross, parity GLT) and UKF
calibration of the isolated gyro (docs/redundant_gyros.md).

:func:`load_config` is the problem's way in: it reads the schema (:mod:`.config`) and checks
the geometry the config describes (:mod:`.geometry`), which itself builds on the schema; it
lives here, above both, so that neither module imports the other back.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from qkf.redundant_gyros.config import GyrosConfig


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> GyrosConfig:
    """Read and validate a gyros config — a path or a preset name (``five_gyros``) — then apply
    ``--set`` overrides. Raises :class:`ConfigError` naming the file and the field; geometry
    problems (a model or the unit without three independent axes) are checked as well."""
    # imported here: `qkf` mounts this package's cli at start-up, which must stay cheap
    from qkf.core import presets
    from qkf.core.config import ConfigError
    from qkf.redundant_gyros.config import PRESETS, GyrosConfig
    from qkf.redundant_gyros.geometry import GeometryError, build_unit

    cfg = presets.load_preset(GyrosConfig, path, PRESETS, overrides)
    source = (
        "<defaults>"
        if path is None
        else str(presets.resolve(path, PRESETS)) + (" (with --set)" if overrides else "")
    )
    try:
        build_unit(cfg)
    except GeometryError as exc:
        raise ConfigError(f"invalid configuration\n  {source}: {exc}") from None
    return cfg


__all__ = ["load_config"]
