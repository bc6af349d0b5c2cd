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
from contextvars import ContextVar
from typing import Any, TypeVar

import numpy as np
from rich.progress import (
    BarColumn,
    Progress,
    ProgressColumn,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.table import Column

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


class ProgressBar:
    """What a run shows while it works: one main task (advanced by calling the bar) and, below
    it, *stages* with their own count (e.g. a method's tuning runs, :func:`progress_stage`).

    Every row has the same five columns, sized for an 80-column terminal: a short description,
    the bar, the percentage, the elapsed time and an *info* field (what is being done now, or
    ``done/total unit``). A disabled bar (``--quiet``) accepts every call and shows nothing.
    """

    def __init__(self, progress: Progress, total: float, label: str, unit: str) -> None:
        self._progress = progress
        self._unit = unit
        self._total = total
        self._done = 0.0
        self._noted = False  # an explicit note replaces the automatic "done/total unit"
        self._main = progress.add_task(label, total=total, info=self._count())

    def _count(self) -> str:
        return f"{self._done:g}/{self._total:g} {self._unit}"

    def __call__(self, n: float = 1) -> None:
        """Advance the main task by ``n`` (of the ``total`` it was created with)."""
        self._done += n
        if self._noted:
            self._progress.update(self._main, advance=n)
        else:
            self._progress.update(self._main, advance=n, info=self._count())

    def note(self, text: str | None) -> None:
        """Show ``text`` in the main task's info field (None: back to ``done/total unit``)."""
        self._noted = text is not None
        self._progress.update(self._main, info=self._count() if text is None else text)

    def stage(self, description: str, total: int, unit: str = "runs") -> Callable[[int], None]:
        """A new row with its own count; returns ``advance(n)`` for it."""
        done = [0]
        task = self._progress.add_task(description, total=total, info=f"0/{total} {unit}")

        def advance(n: int = 1) -> None:
            done[0] += n
            self._progress.update(task, advance=n, info=f"{done[0]}/{total} {unit}")

        return advance


_ACTIVE: ContextVar[ProgressBar | None] = ContextVar("qkf_progress_bar", default=None)


def progress_stage(description: str, total: int, unit: str = "runs") -> Callable[[int], None]:
    """A counted stage below the progress bar of the run in progress, if any; returns
    ``advance(n)`` (a no-op outside a run). For one-off work a method does before the trials,
    such as tuning in its ``prepare``, whose signature has no room for a progress callback."""
    bar = _ACTIVE.get()
    if bar is None:
        return _ignore
    return bar.stage(description, total, unit)


def _ignore(n: int = 1) -> None:
    """``advance`` of a stage outside any run: nothing to show."""


def _progress_columns() -> list[ProgressColumn]:
    # fixed widths: the description and the info field are ellipsized rather than wrapped, so a
    # row stays one readable line at 80 columns (a 10-method label list used to collapse it)
    return [
        TextColumn(
            "[bold]{task.description}",
            table_column=Column(no_wrap=True, overflow="ellipsis", max_width=24),
        ),
        BarColumn(bar_width=14),
        TaskProgressColumn(),
        TimeElapsedColumn(),
        TextColumn(
            "{task.fields[info]}",
            table_column=Column(no_wrap=True, overflow="ellipsis", max_width=34),
        ),
    ]


@contextmanager
def progress_bar(
    total: float, label: str, enabled: bool = True, unit: str = "trials"
) -> Iterator[ProgressBar]:
    """A rich progress bar (:class:`ProgressBar`) over ``total`` units of work; calling it
    advances it. While it is open, :func:`progress_stage` adds rows to it."""
    with Progress(*_progress_columns(), disable=not enabled, transient=False) as progress:
        bar = ProgressBar(progress, total, label, unit)
        token = _ACTIVE.set(bar)
        try:
            yield bar
        finally:
            _ACTIVE.reset(token)
