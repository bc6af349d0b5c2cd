"""Several training runs side by side (``qkf zoo train``'s seeds), on the backends of
:mod:`qkf.core.montecarlo`: local processes (the default) or Ray tasks.

Each run is one task, a whole :func:`~agents.training.run_training` in a process of its own.
A run's result does not depend on where it runs: its torch threads are its config's
``torch_threads`` wherever it runs, numba's threads only split the rows of the environment's
batch (each row is computed alone), and every random draw comes from the run's own seed. So
each seed's network is bit for bit the one a sequential run trains
(``tests/test_zoo.py::test_zoo_train_and_evaluate`` checks it).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path

import numpy as np

from agents.training.plan import TrainPlan
from agents.training.records import remove_staging
from qkf.core.montecarlo import run_chunks


def _train_at(plans: tuple[TrainPlan, ...], ids: np.ndarray) -> list[str]:
    """Run the plans ``ids`` (a task of :func:`run_chunks`); the saved models' paths. A Ctrl-C
    leaves no half-written run in a staging folder."""
    from agents.training import run_training

    models = []
    for i in ids:
        plan = plans[int(i)]
        try:
            models.append(str(run_training(plan, progress=False)))
        except KeyboardInterrupt:
            remove_staging(plan.out)
            raise
    return models


def default_workers(plans: Sequence[TrainPlan]) -> int:
    """As many runs at once as the cores hold at their configured torch threads (at least 1,
    at most one per run)."""
    threads = max(p.cfg.torch_threads for p in plans) if plans else 1
    return max(1, min(len(plans), (os.cpu_count() or 1) // threads))


def train_side_by_side(
    plans: Sequence[TrainPlan],
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
    progress: bool = True,
    on_done: Callable[[int, Path], None] | None = None,
) -> list[Path]:
    """Carry out every plan; the saved models, in the plans' order. ``workers``: local
    processes at once (default :func:`default_workers`; 1: in this process, with the usual
    progress bar); ``backend="ray"``: one Ray task per run (``address``, else ``RAY_ADDRESS``,
    else a local cluster). ``on_done(i, model)`` is called as each run's result comes back, in
    order."""
    from agents.training import run_training

    todo = [i for i, p in enumerate(plans) if not p.complete]
    models: dict[int, Path] = {i: p.model_path for i, p in enumerate(plans) if p.complete}
    workers = default_workers([plans[i] for i in todo]) if workers is None else workers
    if backend == "local" and (workers <= 1 or len(todo) <= 1):
        for i in todo:
            try:
                models[i] = run_training(plans[i], progress=progress)
            except KeyboardInterrupt:
                remove_staging(plans[i].out)
                raise
            if on_done is not None:
                on_done(i, models[i])
    elif todo:
        task = partial(_train_at, tuple(plans))
        chunks = [np.array([i]) for i in todo]
        for ids, result in zip(chunks, run_chunks(task, chunks, backend, workers, address),
                               strict=True):  # fmt: skip
            models[int(ids[0])] = Path(result[0])
            if on_done is not None:
                on_done(int(ids[0]), models[int(ids[0])])
    return [models[i] for i in range(len(plans))]
