"""Chunked Monte Carlo runner and its backends (docs/architecture.md, "Monte Carlo").

A problem package splits its trials into chunks and hands a *task* — a picklable callable
``task(trial_ids) -> result`` — to :func:`run_chunks`, which yields the results **in chunk
order**, whatever order the backend finishes them in. Combining them in that order makes every
backend give the same numbers, bit for bit.

Backends (:data:`BACKENDS`):

* ``local``: in this process (``workers=1``) or a pool of spawned processes, one numba thread each;
* ``ray``: one Ray task per chunk, on the cluster at ``ray_address`` (else ``RAY_ADDRESS``, else
  a local one).

Tasks travel to workers by pickling: functions are pickled by reference, so a task built from a
module-level function and plain data (``functools.partial``) works everywhere, user code
included, as long as the workers can import its module.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

R = TypeVar("R")
Task = Callable[[np.ndarray], R]


def chunk_ids(trials: int, chunk: int) -> list[np.ndarray]:
    """Trial indices ``0 … trials−1`` in consecutive chunks of at most ``chunk``."""
    if trials < 1 or chunk < 1:
        raise ValueError("trials and chunk size must be at least 1")
    return [np.arange(lo, min(trials, lo + chunk)) for lo in range(0, trials, chunk)]


def _single_thread_worker() -> None:
    # each process is one worker: numba's own threads would oversubscribe the cores
    import numba

    numba.set_num_threads(1)


def _run_local(task: Task[R], chunks: list[np.ndarray], workers: int, _: str | None) -> Iterator[R]:
    if workers <= 1:
        for ids in chunks:
            yield task(ids)
        return
    # spawn, not fork: the parent's numba threads (OpenMP) do not survive a fork
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_single_thread_worker) as pool:
        futures = [pool.submit(task, ids) for ids in chunks]
        for fut in futures:
            yield fut.result()


def _call(task: Task[R], ids: np.ndarray) -> R:
    return task(ids)


def _run_ray(task: Task[R], chunks: list[np.ndarray], _: int, address: str | None) -> Iterator[R]:
    try:
        import ray
    except ImportError:  # pragma: no cover - depends on the extra
        raise RuntimeError("the ray backend needs the extra: pip install -e '.[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:
        address = address or os.environ.get("RAY_ADDRESS")
        # no address: a local cluster on this machine
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    try:
        remote: Any = ray.remote(num_cpus=1)(_call)
        refs = [remote.remote(task, ids) for ids in chunks]
        for ref in refs:
            yield ray.get(ref)
    finally:
        if started_here:
            ray.shutdown()


Backend = Callable[[Task[Any], list[np.ndarray], int, str | None], Iterator[Any]]
BACKENDS: dict[str, Backend] = {"local": _run_local, "ray": _run_ray}
"""Backends by name: ``backend(task, chunks, workers, address)`` yields results in chunk order."""


def run_chunks(
    task: Task[R],
    chunks: list[np.ndarray],
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
) -> Iterator[R]:
    """Results of ``task`` on every chunk, in chunk order (see the module docstring)."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}: {' or '.join(BACKENDS)}")
    return BACKENDS[backend](task, chunks, workers, address)


@contextmanager
def progress_bar(total: int, label: str, enabled: bool = True) -> Iterator[Callable[[int], None]]:
    """A rich progress bar over trials; yields ``advance(n)``."""
    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("trials"),
        TimeElapsedColumn(),
        disable=not enabled,
        transient=False,
    ) as bar:
        task_id = bar.add_task(label, total=total)
        yield lambda n: bar.advance(task_id, n)
