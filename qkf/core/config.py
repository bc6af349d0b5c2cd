"""Config machinery shared by every estimation problem (docs/architecture.md, "Configs").

A problem package defines its schema as :class:`StrictModel` subclasses (unknown keys are errors,
so a typo never falls back to a default silently) and loads it with :func:`load_model`, which
reads YAML, applies ``--set dotted.key=value`` overrides and raises :class:`ConfigError` with a
message naming the file and the dotted field. Values carry their display unit in their name
(``rate_deg_s``); the problem package converts to SI.

Numbers must be numbers: every ``int`` or ``float`` of a :class:`StrictModel` (inside tuples,
lists, unions and constraints too) refuses ``true``/``false`` and strings, which pydantic's lax
mode would otherwise turn into 1.0 or parse (``duration_s: true`` ran a 1-second scenario).
YAML files and ``--set`` values are read so that ``1e5`` is a number, as in YAML 1.2 (PyYAML's
YAML 1.1 reads it as the string ``'1e5'``, which would then be refused).
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    GetCoreSchemaHandler,
    ValidationError,
    model_validator,
)
from pydantic_core import (
    CoreSchema,
    PydanticCustomError,
    SchemaError,
    SchemaValidator,
    core_schema,
)

PositiveFloat = Annotated[float, Field(gt=0.0)]
NonNegativeFloat = Annotated[float, Field(ge=0.0)]

M = TypeVar("M", bound=BaseModel)


class ConfigError(ValueError):
    """A configuration that cannot be used; the message names the file and the field."""


def _refuse_non_number(value: Any, kind: str, error_type: str) -> Any:
    """``value`` unchanged, unless it is a bool, a string or bytes (``kind``: what was expected).

    The error's type is pydantic's own (``float_type``, ``int_type``) so callers that look at
    error types see the usual ones; only the message is ours.
    """
    if isinstance(value, bool):
        got = "true" if value else "false"  # as YAML spells it
    elif isinstance(value, str):
        got = f"the string {value!r}" + (" (write it without quotes)" if _numeric(value) else "")
    elif isinstance(value, bytes | bytearray):
        got = "binary data"
    else:
        return value
    raise PydanticCustomError(
        error_type, "Input should be {kind}, not {got}", {"kind": kind, "got": got}
    )


def _numeric(text: str) -> bool:
    """Whether ``text`` reads as a finite number (then the hint is: drop the quotes)."""
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def _number_only(value: Any) -> Any:
    return _refuse_non_number(value, "a number", "float_type")


def _integer_only(value: Any) -> Any:
    return _refuse_non_number(value, "an integer", "int_type")


_GUARDS: dict[str, Callable[[Any], Any]] = {"float": _number_only, "int": _integer_only}
"""The guard put in front of each numeric core schema, by the schema's type."""
_NOT_SCHEMAS = frozenset({"metadata", "serialization", "default", "ref", "config", "cls"})
"""Keys of a core schema whose values are not sub-schemas to guard (data, not validators)."""


def _guard_numbers(schema: Any) -> Any:
    """A copy of a pydantic core schema with every ``float`` and ``int`` schema behind a guard
    that refuses bools and strings before pydantic's lax coercion sees them.

    Working on the core schema (not on annotations) lets pydantic keep doing everything else:
    list → tuple conversion, unions, ``Optional``, constraints, and error locations down to the
    tuple index (``truth.bias_degph.1``). Guarded schemas are left as they are, so building a
    nested model's schema twice is harmless.
    """
    if isinstance(schema, list):
        return [_guard_numbers(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    kind = schema.get("type")
    if kind in _GUARDS:
        return core_schema.no_info_before_validator_function(_GUARDS[kind], schema)
    if kind == "function-before" and schema.get("function", {}).get("function") in (
        _number_only,
        _integer_only,
    ):
        return schema
    out: dict[str, Any] = {}
    for key, value in schema.items():
        if key in _NOT_SCHEMAS:
            out[key] = value
        elif kind == "union" and key == "choices":
            out[key] = [_guard_choice(c) for c in value]
        else:
            out[key] = _guard_numbers(value)
    return out


def _guard_choice(choice: Any) -> Any:
    """A union member, guarded, under the label pydantic gave it unguarded: errors read
    ``misalignment_urad.float``, not ``misalignment_urad.function-before[…]``."""
    if isinstance(choice, tuple):
        return (_guard_numbers(choice[0]), choice[1])
    guarded = _guard_numbers(choice)
    if guarded == choice:  # nothing numeric inside: as pydantic made it
        return choice
    try:
        label = SchemaValidator(choice).title
    except SchemaError:  # a member referring to definitions elsewhere: no label of its own
        return guarded
    return (guarded, label)


class StrictModel(BaseModel):
    """Base of every config model: unknown keys are refused, instances are immutable, NaN and
    infinities are refused (a non-finite number in a config is always a mistake), and numeric
    fields refuse bools and strings (:func:`_guard_numbers`; an int is still fine for a float,
    a list for a tuple)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @classmethod
    def __get_pydantic_core_schema__(
        cls, source: type[BaseModel], handler: GetCoreSchemaHandler, /
    ) -> CoreSchema:
        # pydantic calls this hook (when a model overrides it) to build the class's own schema
        # and each schema it is nested in; handler(source) is pydantic's usual schema
        schema: CoreSchema = _guard_numbers(handler(source))
        return schema


class ProblemConfig(StrictModel):
    """The root of a problem's config: its ``name`` and ``description`` (shown in reports and
    recorded in ``run.json``), then the problem's own sections (docs/architecture.md, "Problem
    shape")."""

    name: str = "custom"
    description: str = ""


class TimeWindow(StrictModel):
    """A time interval ``[start_s, end_s)`` in seconds, non-empty."""

    start_s: NonNegativeFloat
    end_s: NonNegativeFloat

    @model_validator(mode="after")
    def _ordered(self) -> TimeWindow:
        if self.end_s <= self.start_s:
            raise ValueError("end_s must be greater than start_s")
        return self


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, with YAML 1.2's floats: ``1e5``, ``1e-20``, ``2.5E3`` (YAML 1.1
    wants a dot and a signed exponent, and PyYAML reads these as strings)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def load_yaml(text: str) -> Any:
    """Parse YAML text safely, reading ``1e5`` as a number (:class:`_Loader`)."""
    return yaml.load(text, Loader=_Loader)  # safe: _Loader derives from SafeLoader


def _parse_override(item: str) -> tuple[list[str], Any]:
    if "=" not in item:
        raise ConfigError(f"--set {item!r}: expected dotted.key=value")
    key, raw = item.split("=", 1)
    parts = [p for p in key.strip().split(".") if p]
    if not parts:
        raise ConfigError(f"--set {item!r}: empty key")
    try:
        value = load_yaml(raw) if raw.strip() else None
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


WORKLOAD_ERROR = "workload"
"""Type of the pydantic error a config raises when its run is too big (the message names the
fields, so it is printed without a location)."""


def workload_error(exc: ConfigError) -> PydanticCustomError:
    """What a model validator raises for a workload :class:`ConfigError`: a pydantic error of
    type :data:`WORKLOAD_ERROR` (a ``ValueError`` would print as ``Value error, …``)."""
    return PydanticCustomError(WORKLOAD_ERROR, "{message}", {"message": str(exc)})


def format_validation(source: str, exc: ValidationError, what: str = "configuration") -> str:
    """One line per problem: ``source: dotted.field: message``."""
    lines = []
    for err in exc.errors():
        loc = ".".join(str(x) for x in err["loc"]) or "(top level)"
        msg = " ".join(str(err["msg"]).split())
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        if err["type"] == WORKLOAD_ERROR and not err["loc"]:
            lines.append(f"{source}: {msg}")
            continue
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
        loaded = load_yaml(p.read_text(encoding="utf-8"))
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
    addressed even when the file left them out. A file refused on its own may be fixed by its
    overrides (a chunk size too big for its duration: ``--set run.chunk_trials=20``); then the
    overrides act on the file as written. Raises :class:`ConfigError`.
    """
    source = str(path) if path is not None else "<defaults>"
    data = read_yaml_mapping(path) if path is not None else {}
    try:
        cfg = validate(model, data, source, what)
    except ConfigError as refused:
        if not overrides:
            raise
        return _fixed_by_overrides(model, data, overrides, source, what, refused)
    if not overrides:
        return cfg
    merged = cfg.model_dump(mode="json")
    for item in overrides:
        apply_override(merged, item)
    return validate(model, merged, f"{source} (with --set)", what)


def _fixed_by_overrides(
    model: type[M],
    data: dict[str, Any],
    overrides: list[str],
    source: str,
    what: str,
    refused: ConfigError,
) -> M:
    """The file's data with the overrides applied as written, validated: a file refused on its
    own for a cross-field limit (trials × epochs, duration / step) can be fixed with ``--set``.
    ``refused`` (the file's own error) if an override needs the defaults to address a key."""
    raw = copy.deepcopy(data)
    try:
        for item in overrides:
            apply_override(raw, item)
    except (ConfigError, LookupError, TypeError):
        # e.g. a list index the file does not have (only the populated defaults do)
        raise refused from None
    return validate(model, raw, f"{source} (with --set)", what)
