"""Registries: named extension points that users fill without editing the package.

A :class:`Registry` maps names to objects (methods, rewards, agents, …). Entries come from
three places, looked up in this order:

1. the package itself (``registry.register(name, obj)``, or as a decorator);
2. installed distributions, through an entry-point group (``[project.entry-points."GROUP"]``
   in their ``pyproject.toml``), loaded on first use;
3. for registries that allow it, a ``module:attribute`` spec, imported on demand
   (:func:`load_object`).

Objects are looked up by name in every process that needs them, so a registered object works
with every Monte Carlo backend as long as its module is importable there.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator
from importlib.metadata import entry_points
from typing import Any, Generic, TypeVar, overload

T = TypeVar("T")


class RegistryError(LookupError):
    """An unknown name or a spec that cannot be loaded; the message says which and why."""


def load_object(spec: str) -> Any:
    """The attribute named by ``"package.module:attribute"`` (attribute may be dotted)."""
    module_name, sep, attr = spec.partition(":")
    if not sep or not module_name or not attr:
        raise RegistryError(f"{spec!r}: expected module:attribute")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise RegistryError(f"{spec!r}: cannot import {module_name}: {exc}") from None
    try:
        return _attribute(module, attr)
    except AttributeError:
        raise RegistryError(f"{spec!r}: {module_name} has no attribute {attr}") from None


def _attribute(obj: Any, dotted: str) -> Any:
    """``obj.a.b`` for ``dotted`` = ``"a.b"``."""
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


class Imported:
    """A class attribute imported when it is read: ``methods = Imported("pkg.module:NAME")``,
    so that the object holding it loads without the module (a problem's facts sheet). A module
    that fails to import raises its own error, traceback and all: it is a fault of the
    installation, not a spec to report."""

    def __init__(self, spec: str) -> None:
        self.module, _, self.attr = spec.partition(":")

    def __get__(self, obj: object, owner: type | None = None) -> Any:
        return _attribute(importlib.import_module(self.module), self.attr)


class Registry(Generic[T]):
    """Names → objects, with entry-point discovery (see the module docstring).

    ``kind`` names what is registered, for messages ("method", "reward").
    """

    def __init__(self, kind: str, group: str | None = None) -> None:
        self.kind = kind
        self.group = group
        self._items: dict[str, T] = {}
        self._loaded_entry_points = False

    @overload
    def register(self, name: str, obj: T) -> T: ...

    @overload
    def register(self, name: str, obj: None = None) -> Callable[[T], T]: ...

    def register(self, name: str, obj: T | None = None) -> T | Callable[[T], T]:
        """Register ``obj`` under ``name`` (or use as ``@registry.register(name)``)."""

        def add(item: T) -> T:
            if name in self._items and self._items[name] is not item:
                raise RegistryError(f"{self.kind} {name!r} is registered twice")
            self._items[name] = item
            return item

        return add if obj is None else add(obj)

    def register_spec(self, name: str, spec: str) -> None:
        """Register the object that ``"module:attribute"`` names, imported on first use (an
        entry a core module declares without importing the package that holds it)."""
        if name in self._items:
            raise RegistryError(f"{self.kind} {name!r} is registered twice")
        self._items[name] = _LazyEntry(_Spec(spec))  # type: ignore[assignment]

    def known(self, name: str, what: str | None = None) -> str:
        """``name`` if it is registered, else ``ValueError`` listing the known names: the check
        of a config field that names an entry (a pydantic validator). ``what`` names the
        entry in the message (default: the registry's ``kind``)."""
        if name not in self:
            raise ValueError(
                f"unknown {what or self.kind} {name!r}; known: {', '.join(self.names())}"
            )
        return name

    def _load_entry_points(self) -> None:
        if self._loaded_entry_points or self.group is None:
            return
        self._loaded_entry_points = True
        for ep in entry_points(group=self.group):
            if ep.name not in self._items:
                self._items[ep.name] = _LazyEntry(ep)  # type: ignore[assignment]

    def names(self) -> list[str]:
        """Every registered name, the package's own first (in registration order)."""
        self._load_entry_points()
        return list(self._items)

    def __contains__(self, name: object) -> bool:
        self._load_entry_points()
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def __getitem__(self, name: str) -> T:
        self._load_entry_points()
        try:
            item = self._items[name]
        except KeyError:
            raise RegistryError(
                f"unknown {self.kind} {name!r}; known: {', '.join(self._items) or 'none'}"
            ) from None
        if isinstance(item, _LazyEntry):
            try:
                loaded: T = item.ep.load()
            except Exception as exc:
                raise RegistryError(f"{self.kind} {name!r} ({item.ep.value}): {exc}") from None
            self._items[name] = loaded
            return loaded
        return item


class _LazyEntry:
    """An entry point not imported yet (importing may be expensive, e.g. torch)."""

    def __init__(self, ep: Any) -> None:
        self.ep = ep


class _Spec:
    """A ``module:attribute`` spec with an entry point's ``load`` and ``value``."""

    def __init__(self, value: str) -> None:
        self.value = value

    def load(self) -> Any:
        return load_object(self.value)
