"""A cache of computed results on disk, keyed by everything they depend on (docs/caching.md).

A judged method gives the same numbers for the same code, configuration, method settings, seed
and trials, whatever else a run contains: the baselines of a families study, say, beside a new
policy. Each result is stored once under a key and read back instead of recomputed.

Key. A JSON-ready mapping, written canonically (sorted keys, no spaces) and hashed with
SHA-256; the digest names the entry. Callers put into it everything the result depends on; this
module adds nothing, except that :func:`code_fingerprint` gives the part that names the code:
the source files of the packages that compute the result, the versions of the numerical
libraries, and the CPU numba compiles for (the last bits of a compiled result depend on it).

Entry. ``<root>/results/<digest[:2]>/<digest>.qkfr``::

    qkf-results <FORMAT>\\n
    <SHA-256 of the body, hex>\\n
    <body: an uncompressed .npz of the arrays and "__meta__", the meta data as UTF-8 JSON>

plus the canonical key inside the meta data, compared on read (a digest collision, or a file
put there by hand, is a miss). A body that does not match its checksum, a truncated file or an
unreadable one is *corrupt*: it is reported, removed and recomputed, never used. Entries are
written atomically (a reader never sees half an entry), so parallel writers of one key are
harmless: both write the same result.

The cache lives under ``$QKF_CACHE_DIR`` (default ``~/.cache/qkf``), beside the tuning cache;
``qkf cache info`` and ``qkf cache clear`` manage it. Only ``*.qkfr`` files under ``results/``
are ever removed.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import platform
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.io import atomic_write_bytes

FORMAT = 1
"""Version of the entry layout; entries of another layout are misses."""
MAGIC = b"qkf-results"
SUFFIX = ".qkfr"
RESULTS_DIR = "results"
NO_CACHE_ENV = "QKF_NO_CACHE"
"""Set to ``1`` to turn the results cache off everywhere (the commands' ``--no-cache``)."""
LIBRARIES = ("numpy", "scipy", "numba", "llvmlite", "filterpy", "torch", "stable-baselines3")
"""Libraries whose version is part of :func:`code_fingerprint`."""


def cache_root() -> Path:
    """``$QKF_CACHE_DIR`` (default ``~/.cache/qkf``)."""
    return Path(os.environ.get("QKF_CACHE_DIR") or os.path.join("~", ".cache", "qkf")).expanduser()


def cache_enabled(requested: bool = True) -> bool:
    """``requested``, unless ``$QKF_NO_CACHE`` is set to anything but ``0`` or empty."""
    return requested and os.environ.get(NO_CACHE_ENV, "") in ("", "0")


def canonical(value: Any) -> str:
    """The one JSON text of a JSON-ready value (sorted keys, no spaces)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)


def key_digest(key: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of the canonical JSON of ``key``."""
    return hashlib.sha256(canonical(key).encode()).hexdigest()


def _library_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def _cpu_name() -> str:
    try:
        import llvmlite.binding as ll

        return f"{ll.get_host_cpu_name()}:{os.environ.get('NUMBA_CPU_NAME', '')}"
    except Exception:  # pragma: no cover - llvmlite is a dependency of numba
        return platform.processor()


@functools.cache
def sources_digest(package_dirs: tuple[Path, ...]) -> str:
    """SHA-256 (hex) over the relative paths and contents of the ``*.py`` files of the given
    package folders (``__pycache__`` left out)."""
    digest = hashlib.sha256()
    for root in package_dirs:
        for path in sorted(root.rglob("*.py")):
            if "__pycache__" in path.parts:
                continue
            rel = f"{root.name}/{path.relative_to(root).as_posix()}"
            digest.update(rel.encode() + b"\0" + hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def code_fingerprint(package_dirs: Iterable[Path]) -> dict[str, Any]:
    """What names the code of a result: the sources of ``package_dirs``, the numerical
    libraries' versions, the machine and the CPU numba compiles for."""
    return {
        "sources": sources_digest(tuple(Path(p) for p in package_dirs)),
        "libraries": {name: _library_version(name) for name in LIBRARIES},
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpu": _cpu_name(),
    }


class CacheWarning(UserWarning):
    """A damaged results-cache entry was found (and recomputed, never used)."""


STATUSES = ("hit", "miss", "corrupt", "off")
"""What one lookup gave: the stored result, none stored, a damaged entry (removed and
recomputed), or a result that is not cached (the cache is off, or the method cannot be
described)."""


@dataclass
class CacheLog:
    """What a run's lookups gave, per method label: the count of each of :data:`STATUSES` (and
    of any further ones a problem counts, e.g. a tuning's ``prepare_hit``), and the damaged
    entries found. What ``run.json`` records."""

    counts: dict[str, dict[str, int]] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    def add(self, label: str, status: str, times: int = 1) -> None:
        """Count ``times`` lookups of ``label`` that gave ``status``."""
        per = self.counts.setdefault(label, dict.fromkeys(STATUSES, 0))
        per[status] = per.get(status, 0) + times


class CorruptEntry(Exception):
    """An entry whose body does not match its checksum, or that cannot be read."""


@dataclass
class Entry:
    """A stored result: arrays by name, and JSON-ready meta data."""

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)


def encode(key: Mapping[str, Any], entry: Entry) -> bytes:
    """The bytes of an entry file (module docstring)."""
    meta = {"key": canonical(key), "meta": entry.meta}
    buffer = io.BytesIO()
    arrays = {f"a_{name}": np.asarray(a) for name, a in entry.arrays.items()}
    arrays["__meta__"] = np.frombuffer(canonical(meta).encode(), dtype=np.uint8)
    np.savez(buffer, allow_pickle=False, **arrays)
    body = buffer.getvalue()
    return b"%s %d\n%s\n%s" % (MAGIC, FORMAT, hashlib.sha256(body).hexdigest().encode(), body)


def decode(raw: bytes, key: Mapping[str, Any]) -> Entry | None:
    """The entry in ``raw``; None if it was written for another key or in another layout;
    :class:`CorruptEntry` if its body does not match its checksum or cannot be read."""
    head, _, rest = raw.partition(b"\n")
    if head != b"%s %d" % (MAGIC, FORMAT):
        if head.startswith(MAGIC + b" "):
            return None  # another layout: a miss, rewritten
        raise CorruptEntry("no entry header")
    checksum, _, body = rest.partition(b"\n")
    if hashlib.sha256(body).hexdigest().encode() != checksum:
        raise CorruptEntry("checksum mismatch (truncated or altered)")
    try:
        with np.load(io.BytesIO(body), allow_pickle=False) as npz:
            arrays = {name[2:]: npz[name] for name in npz.files if name.startswith("a_")}
            meta = json.loads(npz["__meta__"].tobytes().decode())
    except (OSError, ValueError, KeyError, UnicodeDecodeError) as exc:
        raise CorruptEntry(f"unreadable body ({exc})") from exc
    if meta.get("key") != canonical(key):
        return None
    return Entry(arrays, meta.get("meta", {}))


@dataclass
class Lookup:
    """The outcome of :meth:`ResultsCache.get`: the entry (None on a miss) and what happened:
    ``hit``, ``miss`` or ``corrupt`` (a damaged entry was found, removed, and is a miss)."""

    entry: Entry | None
    status: str
    detail: str = ""


class ResultsCache:
    """Entries under ``root/results`` (``root``: :func:`cache_root` unless given)."""

    def __init__(self, root: Path | None = None) -> None:
        self.folder = (cache_root() if root is None else Path(root)) / RESULTS_DIR

    def path(self, digest: str) -> Path:
        """The file of the entry whose key has SHA-256 ``digest``."""
        return self.folder / digest[:2] / f"{digest}{SUFFIX}"

    def get(self, key: Mapping[str, Any]) -> Lookup:
        """The entry of ``key``, if stored and intact (a corrupt one is removed)."""
        path = self.path(key_digest(key))
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            return Lookup(None, "miss")
        except OSError as exc:
            return Lookup(None, "miss", f"unreadable: {exc}")
        try:
            entry = decode(raw, key)
        except CorruptEntry as exc:
            path.unlink(missing_ok=True)
            return Lookup(None, "corrupt", f"{path}: {exc}")
        return Lookup(entry, "hit") if entry is not None else Lookup(None, "miss")

    def put(self, key: Mapping[str, Any], entry: Entry) -> None:
        """Store ``entry`` under ``key`` (atomically; an unwritable cache is skipped)."""
        path = self.path(key_digest(key))
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(path, encode(key, entry))
        except OSError:
            pass  # a read-only or full cache only costs the recomputation next time

    def entries(self) -> list[Path]:
        """Every entry file (only ``*.qkfr`` files in the two-hex-digit folders)."""
        if not self.folder.is_dir():
            return []
        return sorted(
            p
            for sub in self.folder.iterdir()
            if sub.is_dir() and len(sub.name) == 2
            for p in sub.glob(f"*{SUFFIX}")
            if p.is_file()
        )

    def clear(self) -> int:
        """Remove every entry (and the folders it leaves empty); the number removed."""
        removed = 0
        for path in self.entries():
            path.unlink(missing_ok=True)
            removed += 1
        if self.folder.is_dir():
            for sub in self.folder.iterdir():
                if sub.is_dir() and len(sub.name) == 2:
                    try:
                        sub.rmdir()
                    except OSError:
                        pass  # holds something else: not ours to remove
        return removed


def describe(obj: Any, _depth: int = 0) -> Any:
    """A JSON-ready description of a method object for a cache key, or None if it cannot be
    described (then its results are not cached).

    An object with a ``cache_token()`` method describes itself. Otherwise a function, class or
    instance defined in the ``qkf`` package is named by module and qualified name (its code
    is in :func:`code_fingerprint`), a closure adds the values it captured, a dataclass or
    plain instance adds its fields, and
    numbers, strings, lists and arrays are themselves. Code from elsewhere is not described:
    its source is not in the fingerprint.
    """
    if _depth > 8:
        return None
    token = getattr(obj, "cache_token", None)
    if callable(token) and not isinstance(obj, type):
        return token()
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, float):
        return repr(obj)  # exact, and JSON has no inf/nan
    if isinstance(obj, np.ndarray | np.generic):
        arr = np.asarray(obj)
        return {"array": hashlib.sha256(arr.tobytes()).hexdigest(), "dtype": str(arr.dtype),
                "shape": list(arr.shape)}  # fmt: skip
    if isinstance(obj, list | tuple):
        items = [describe(v, _depth + 1) for v in obj]
        lost = any(i is None and v is not None for i, v in zip(items, obj, strict=True))
        return None if lost else items
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            d = describe(v, _depth + 1)
            if d is None and v is not None:
                return None
            out[str(k)] = d
        return out
    closure = getattr(obj, "__closure__", None)
    if closure and callable(obj) and not isinstance(obj, type):
        # a function made inside another: what it captured is part of what it computes (two
        # closures of one factory share a name), so the captured values are described too
        cells = []
        for cell in closure:
            try:
                value = cell.cell_contents
            except ValueError:  # an empty cell: nothing to describe it by
                return None
            cells.append(describe(value, _depth + 1))
            if cells[-1] is None and value is not None:
                return None
        module = getattr(obj, "__module__", "") or ""
        if module != "qkf" and not module.startswith("qkf."):
            return None
        return {"closure": f"{module}:{obj.__qualname__}", "cells": cells}
    if isinstance(obj, functools.partial):
        parts = [describe(obj.func, _depth + 1), describe(obj.args, _depth + 1),
                 describe(obj.keywords, _depth + 1)]  # fmt: skip
        return None if None in parts else {"partial": parts}
    kind = (
        obj
        if isinstance(obj, type) or (callable(obj) and hasattr(obj, "__qualname__"))
        else type(obj)
    )
    module = getattr(kind, "__module__", "") or ""
    if module != "qkf" and not module.startswith("qkf."):
        return None
    name = f"{module}:{kind.__qualname__}"
    if kind is obj:
        return name
    fields = getattr(obj, "__dict__", None)
    if fields is None:
        return {"type": name}
    described = describe(dict(fields), _depth + 1)
    return None if described is None else {"type": name, "fields": described}
