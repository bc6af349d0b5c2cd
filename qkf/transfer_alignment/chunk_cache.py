"""What one method contributes to one chunk of a benchmark, kept in the results cache.

:func:`~qkf.transfer_alignment.benchmark.run_chunk` asks here before running a method on a
chunk of simulated trials (docs/caching.md). The key holds everything the contribution depends
on:

* ``code``: :func:`~qkf.core.results_cache.code_fingerprint` of the package (and of the
  packages a method names through its own ``cache_token``, a policy's);
* ``config``: the resolved config, less what only says how the run is carried out or reported
  (``run.trials``, ``run.seed``, ``run.workers``, ``run.ray_address``, ``run.chunk_trials``,
  ``run.bootstrap``, ``run.baseline``, ``name``, ``description``): the seed and the trials are
  keyed on their own;
* ``method``: the prepared method as :func:`~qkf.core.results_cache.describe` gives it (a tuned
  method with its tuned values; a policy with its model file's SHA-256);
* ``seed`` and ``trials``: the chunk's trial ids.

A method that cannot be described (code from outside the package, with no ``cache_token``) is
run every time. Simulated trials only: recorded data are not cached.

A method's preparation (``prepare(cfg)``: kf-tuned's κ, the clock's and the oracle's schedules,
the tuned values of the ``-tuned`` methods, all tuned on the tuning seeds) is cached the same way
(:func:`cached_prepare`), keyed by the code, the config and the unprepared method.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from qkf.core.results_cache import Entry, ResultsCache, code_fingerprint, describe, key_digest
from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.divergence import Divergence
from qkf.transfer_alignment.methods.base import Method, prepare

PACKAGE = Path(__file__).resolve().parents[1]
"""The ``qkf`` package folder: its sources name the code of every built-in method."""

KEY_VERSION = 1
"""Bumped when what a chunk entry holds changes."""

_RUN_ONLY = ("trials", "seed", "workers", "ray_address", "chunk_trials", "bootstrap", "baseline")

ARRAYS = ("sum_sq", "trial_ms", "band_ms", "kappa", "nees_sum", "nees_count")
"""The per-method arrays of a :class:`~qkf.transfer_alignment.benchmark.ChunkResult`
(``kappa`` and ``nees_sum`` may be None)."""


def config_key(cfg: Config) -> dict[str, Any]:
    """The config as it bears on a method's results (module docstring)."""
    data = cfg.model_dump(mode="json")
    for name in ("name", "description"):
        data.pop(name, None)
    run = data.get("run", {})
    for name in _RUN_ONLY:
        run.pop(name, None)
    return data


def _key(kind: str, cfg: Config, method: object, **more: Any) -> dict[str, Any] | None:
    """A key of this module: the kind, the code, the config as it bears on results and the
    method, plus ``more``; None if the method cannot be described (then it is not cached)."""
    token = describe(method)
    if token is None:
        return None
    return {
        "kind": f"transfer_alignment.{kind}",
        "version": KEY_VERSION,
        "code": code_fingerprint([PACKAGE]),
        "config": config_key(cfg),
        "method": token,
        **more,
    }


def chunk_key(cfg: Config, method: object, seed: int, ids: np.ndarray) -> dict[str, Any] | None:
    """The key of ``method`` on trials ``ids`` of ``seed`` (None: not cached)."""
    return _key("chunk", cfg, method, seed=int(seed), trials=[int(i) for i in ids])


def to_entry(parts: dict[str, Any]) -> Entry:
    """An entry from one method's part of a chunk (the fields of ``ChunkResult`` for it)."""
    arrays = {name: parts[name] for name in ARRAYS if parts[name] is not None}
    divergences = [
        {
            "trial": d.trial,
            "epoch": d.epoch,
            "t_s": None if math.isnan(d.t_s) else d.t_s,
            "cause": d.cause,
        }
        for d in parts["divergences"]
    ]
    meta = {
        "diverged": int(parts["diverged"]),
        "runtime_s": float(parts["runtime_s"]),
        "notes": dict(parts["notes"]),
        "divergences": divergences,
    }
    return Entry(arrays, meta)


def from_entry(entry: Entry, label: str) -> dict[str, Any]:
    """One method's part of a chunk, reported under ``label``, from its entry."""
    meta = entry.meta
    parts: dict[str, Any] = {name: entry.arrays.get(name) for name in ARRAYS}
    parts["diverged"] = int(meta["diverged"])
    parts["runtime_s"] = float(meta["runtime_s"])
    parts["notes"] = {str(k): str(v) for k, v in meta["notes"].items()}
    parts["divergences"] = [
        Divergence(
            label,
            int(d["trial"]),
            int(d["epoch"]),
            math.nan if d["t_s"] is None else float(d["t_s"]),
            str(d["cause"]),
        )
        for d in meta["divergences"]
    ]
    return parts


def prepare_key(cfg: Config, method: object) -> dict[str, Any] | None:
    """The key of ``method.prepare(cfg)`` (its tuning on the tuning seeds): the code, the
    config as it bears on results, and the unprepared method; None if it cannot be described."""
    return _key("prepare", cfg, method)


def lookup_prepared(
    method: Method, cfg: Config, cache: bool
) -> tuple[Method | None, str, dict[str, Any] | None]:
    """The prepared ``method`` from the results cache (None if it must be prepared), what
    happened (``hit``, ``miss``, ``corrupt``, or ``off``: not cached or a method that cannot
    be described), and the key to store a fresh preparation under (None: do not store). The
    prepared method is kept pickled (what the workers receive anyway); an entry that does not
    unpickle counts as damaged."""
    key = prepare_key(cfg, method) if cache else None
    if key is None:
        return None, "off", None
    lookup = ResultsCache().get(key)
    if lookup.entry is not None:
        try:
            return pickle.loads(lookup.entry.arrays["pickle"].tobytes()), "hit", key
        except Exception:  # a damaged pickle behind an intact checksum: recompute
            return None, "corrupt", key
    return None, lookup.status, key


def store_prepared(key: dict[str, Any] | None, prepared: Method) -> None:
    """Keep a fresh preparation under ``key`` (from :func:`lookup_prepared`; None: nothing)."""
    if key is not None:
        blob = np.frombuffer(pickle.dumps(prepared, protocol=5), dtype=np.uint8)
        ResultsCache().put(key, Entry({"pickle": blob}))


def cached_prepare(method: Method, cfg: Config, cache: bool) -> tuple[Method, str]:
    """``prepare(method, cfg)``, from the results cache where it holds it (``cache``), and what
    happened (:func:`lookup_prepared`); ``off`` for a method with nothing to prepare."""
    if not callable(getattr(method, "prepare", None)):
        return method, "off"
    found, status, key = lookup_prepared(method, cfg, cache)
    if found is not None:
        return found, status
    prepared = prepare(method, cfg)
    store_prepared(key, prepared)
    return prepared, status


def prepare_at(cfg: Config, methods: tuple[Method, ...], ids: np.ndarray) -> list[Method]:
    """``prepare`` of ``methods[i]`` for ``i`` in ``ids``: the unit of work of a backend when
    the tunings run side by side (:func:`~qkf.transfer_alignment.benchmark.run_benchmark`)."""
    return [prepare(methods[int(i)], cfg) for i in ids]


def preparation_cached(method: Method, cfg: Config) -> bool:
    """Whether the results cache holds ``method``'s preparation for ``cfg`` (a cheap look:
    the entry's file exists; it is checked when read)."""
    key = prepare_key(cfg, method)
    return key is not None and ResultsCache().path(key_digest(key)).is_file()
