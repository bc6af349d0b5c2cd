"""Policies trained over several seeds, judged as one (docs/zoo.md, "families:").

A policy trained with seeds ``s₁ … sₖ`` is run as ``k`` methods labelled ``NAME#s₁ … NAME#sₖ``
(:data:`SEED_MARK`). :func:`seed_statistics` pools them the way rliable recommends (Agarwal et
al. 2021): the interquartile mean over seeds × trials of a per-trial score normalised by a
reference method, with a stratified bootstrap interval, and the probability of improvement
over each baseline. Any problem's per-trial errors can be pooled this way; the error is lower
is better, the score ``error_reference / error_policy`` higher is better.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager

import numpy as np

SEED_MARK = "#"
"""``NAME#SEED`` labels: the training seeds of one policy, pooled by :func:`seed_statistics`."""


@contextmanager
def _numpy_global_seed(seed: int) -> Iterator[None]:
    """numpy's global random state seeded with ``seed`` inside the block, restored after it.

    rliable 1.2's ``StratifiedBootstrap.update_indices`` draws its resamples with
    ``np.random.choice`` (the global state), not from the ``random_state`` it is handed, so
    without this its intervals change from call to call and with whatever ran before in the
    process (tests/test_seed_groups.py shows it)."""
    saved = np.random.get_state()  # noqa: NPY002 (rliable draws from this global state)
    np.random.seed(seed)  # noqa: NPY002
    try:
        yield
    finally:
        np.random.set_state(saved)  # noqa: NPY002


def seed_groups(labels: Sequence[str]) -> dict[str, list[str]]:
    """``NAME`` → its ``NAME#SEED`` labels among ``labels``, in their order."""
    groups: dict[str, list[str]] = {}
    for label in labels:
        name, mark, _ = label.partition(SEED_MARK)
        if mark:
            groups.setdefault(name, []).append(label)
    return groups


def seed_statistics(
    errors: Mapping[str, np.ndarray],
    baselines: Sequence[str],
    reference: str,
    level: float,
    reps: int = 2000,
    seed: int = 0,
) -> list[dict[str, object]]:
    """For every policy run over several training seeds among ``errors`` (label → the judged
    error per trial, every label over the same trials): rliable's IQM over seeds × trials of the
    score ``error_reference / error_policy`` per trial (above 1 is better), with its stratified
    bootstrap interval at ``level`` (``reps`` resamples, numpy seed ``seed``), and the
    probability of improvement over each of ``baselines`` that ran
    (P(score_policy > score_baseline), rliable's Mann–Whitney form averaged over trials).
    Empty without seed groups or without ``reference``."""
    if reference not in errors:
        return []
    ref = np.asarray(errors[reference], dtype=float)
    groups = seed_groups(list(errors))
    if not groups:
        return []
    from rliable import library as rly
    from rliable import metrics as rlm

    def score(m: str) -> np.ndarray:
        return ref / np.asarray(errors[m], dtype=float)

    out: list[dict[str, object]] = []
    state = np.random.RandomState(seed)
    for name, labels in sorted(groups.items()):
        runs = np.stack([score(m) for m in labels])  # (seeds, trials)
        with warnings.catch_warnings(), _numpy_global_seed(seed + len(out)):
            warnings.simplefilter("ignore", FutureWarning)  # rliable hands arch a RandomState
            point, intervals = rly.get_interval_estimates(
                {name: runs}, lambda x: np.array([rlm.aggregate_iqm(x)]), reps=reps,
                confidence_interval_size=level, random_state=state,
            )  # fmt: skip
        row: dict[str, object] = {
            "policy": name,
            "seeds": len(labels),
            "iqm": float(point[name][0]),
            "iqm_lo": float(intervals[name][0, 0]),
            "iqm_hi": float(intervals[name][1, 0]),
        }
        for b in baselines:
            if b in errors and SEED_MARK not in b:
                row[f"p_improve_{b}"] = float(
                    rlm.probability_of_improvement(runs, score(b)[None, :])
                )
        out.append(row)
    return out


__all__ = ["SEED_MARK", "seed_groups", "seed_statistics"]
