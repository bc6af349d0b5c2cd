"""Config machinery shared by every estimation problem (docs/architecture.md, "Configs").

A problem package defines its schema as :class:`StrictModel` subclasses (unknown keys are errors,
so a typo never falls back to a default silently) and loads it with :func:`load_model`, which
reads YAML, applies ``--set dotted.key=value`` overrides and raises :class:`ConfigError` with a
message naming the file and the dotted field. Values carry their display unit in their name
(``rate_deg_s``); the problem package converts to SI.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

PositiveFloat = Annotated[float, Field(gt=0.0)]
NonNegativeFloat = Annotated[float, Field(ge=0.0)]

M = TypeVar("M", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the file and the field."""


class StrictModel(BaseModel):
    """Base of every config model: unknown keys are refused, instances are immutable, NaN and
    infinities are refused (a non-finite number in a config is always a mistake)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TimeWindow(StrictModel):
    """A time interval ``[start_s, end_s)`` in seconds, non-empty."""

    start_s: NonNegativeFloat
    end_s: NonNegativeFloat

    @model_validator(mode="after")
    def _ordered(self) -> TimeWindow:
        if self.end_s <= self.start_s:
            raise ValueError("end_s must be greater than start_s")
        return self


def _parse_override(item: str) -> tuple[list[str], Any]:
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected dotted.key=value")
    key, raw = item.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if not parts:
        raise ConfigError(f"--set {item!r}: empty key")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {item!r}: cannot parse value: {exc}") from exc
    return parts, value


def apply_override(data: dict[str, Any], item: str) -> None:
    """Apply one ``dotted.key=value`` override (value parsed as YAML) to a raw config dict.

    List items are addressed by index (``maneuvers.1.rate_deg_s=2``); missing intermediate
    mappings are created, and validation afterwards refuses keys the schema does not know.
    """
    parts, value = _parse_override(item)
    node: Any = data
    for i, part in enumerate(parts[:-1]):
        if isinstance(node, list):
            node = node[_list_index(part, node, item)]
            continue
        if part not in node or node[part] is None:
            node[part] = {}
        elif not isinstance(node[part], dict | list):
            raise ConfigError(f"--set {item!r}: {'.'.join(parts[: i + 1])} is not a mapping")
        node = node[part]
    last = parts[-1]
    if isinstance(node, list):
        node[_list_index(last, node, item)] = value
    else:
        node[last] = value


def _list_index(part: str, node: list[Any], item: str) -> int:
    if not part.lstrip("-").isdigit() or not -len(node) <= int(part) < len(node):
        raise ConfigError(f"--set {item!r}: {part!r} is not an index of a list of {len(node)}")
    return int(part)


def format_validation(source: str, exc: ValidationError, what: str = "configuration") -> str:
    """One line per problem: ``source: dotted.field: message``."""
    lines = []
    for err in exc.errors():
        loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
        msg = " ".join(str(err["msg"]).split())
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        lines.append(f"{source}: {loc}: {msg}")
    return f"invalid {what}\n  " + "\n  ".join(lines)


def read_yaml_mapping(path: str | Path, what: str = "config") -> dict[str, Any]:
    """The top-level mapping of a YAML file; ``ConfigError`` for anything else, including an
    empty file (which would otherwise run silently as the defaults)."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{p}: is a directory, not a {what} file")
    if not p.is_file():
        raise ConfigError(f"{p}: no such {what} file")
    try:
        loaded = yaml.safe_load(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{p}: not a text file (UTF-8): {exc.reason} at byte {exc.start}"
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML: {_one_line(exc)}") from None
    except RecursionError:
        raise ConfigError(f"{p}: nested too deeply") from None
    if loaded is None:
        raise ConfigError(f"{p}: empty {what} file (write the keys that differ from the defaults)")
    if not isinstance(loaded, dict):
        raise ConfigError(f"{p}: top level must be a mapping, not {type(loaded).__name__}")
    bad = [k for k in loaded if not isinstance(k, str)]
    if bad:
        raise ConfigError(f"{p}: {bad[0]!r}: keys must be strings")
    return loaded


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())


def validate(model: type[M], data: dict[str, Any], source: str, what: str = "configuration") -> M:
    """``model.model_validate(data)`` with errors turned into a :class:`ConfigError`."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation(source, exc, what)) from None
    except RecursionError:
        raise ConfigError(f"{source}: nested too deeply") from None


def load_model(
    model: type[M],
    path: str | Path | None = None,
    overrides: list[str] | None = None,
    what: str = "configuration",
) -> M:
    """Read and validate ``path`` (``None``: the model's defaults), then apply overrides.

    Overrides act on the fully populated config, so list items and nested defaults can be
    addressed even when the file left them out. Raises :class:`ConfigError`.
    """
    source = str(path) if path is not None else "<defaults>"
    data = read_yaml_mapping(path) if path is not None else {}
    cfg = validate(model, data, source, what)
    if not overrides:
        return cfg
    merged = cfg.model_dump(mode="json")
    for item in overrides:
        apply_override(merged, item)
    return validate(model, merged, f"{source} (with --set)", what)
