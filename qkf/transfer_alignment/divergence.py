r"""Divergence: where a method's run stopped meaning anything (docs/recorded_data.md,
"Divergence"; docs/methods.md).

A run *diverges* at the first epoch where

- its estimate is not finite (the filter kernel freezes a trial whose state or covariance is
  not finite, or whose covariance lost positive definiteness, and records NaN from there);
- a reported variance is infinite or negative;
- its innovations leave any plausible range for a sustained stretch: the NIS of a block, over
  its ``m`` rows, exceeds :data:`NIS_IMPLAUSIBLE` ``· m`` at :data:`NIS_RUN` consecutive
  updates of that block. A consistent filter's NIS is ``χ²(m)``; a filter whose assumed noise is
  wrong by a factor ``f`` in σ sees NIS of about ``f² m``. The noise-mismatch studies reach
  ``f = 10/3`` (NIS/m ≈ 11); the threshold, ``f = 100``, is two orders of magnitude beyond,
  and ten consecutive updates there have no probability under any model the filter could be
  right about. Such a filter no longer tracks the data, even while its numbers stay finite;
- the method itself flagged the trial (``MethodOutput.diverged``) without any of the above.

``qkf bench`` reports every divergence in ``summary.md`` and on the terminal (method, trial or
file, epoch, time, cause) and exits with :data:`EXIT_DIVERGED`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from qkf.transfer_alignment.methods.base import MethodOutput

EXIT_DIVERGED = 3
"""Exit code of ``qkf bench`` when a method diverged (its outputs are written and say where)."""
NIS_IMPLAUSIBLE = 1.0e4
"""NIS per innovation row above which an update is implausible under any noise level the filter
could be off by (innovations 100 σ)."""
NIS_RUN = 10
"""Consecutive implausible updates that make a divergence."""
DIVERGED_HEADING = "## Diverged"
"""The heading of summary.md's section on divergences (a sweep's command finds it per case)."""
BLOCKS: tuple[tuple[str, int], ...] = (("attitude", 3), ("rate", 3))
"""The NIS columns of :class:`MethodOutput` (``nis[..., c]``): block name and rows."""


@dataclass(frozen=True)
class Divergence:
    """Where one trial of one method diverged."""

    method: str
    trial: int  # the trial id (recorded data: the file's index)
    epoch: int  # first epoch of the divergence; -1: flagged by the method, epoch unknown
    t_s: float  # its time from the run's start, s (NaN when the epoch is unknown)
    cause: str

    def describe(self, where: str | None = None) -> str:
        """``method kf, trial 3 (FILE), epoch 120 (t = 120 s): cause``."""
        trial = f"trial {self.trial}" + (f" ({where})" if where else "")
        at = "" if self.epoch < 0 else f", epoch {self.epoch} (t = {self.t_s:.6g} s)"
        return f"method {self.method}, {trial}{at}: {self.cause}"


def _first_run(flags: np.ndarray, length: int) -> int | None:
    """Index of the first of ``length`` consecutive True values in ``flags``, or None."""
    if flags.size < length:
        return None
    runs = np.convolve(flags.astype(np.int64), np.ones(length, dtype=np.int64), "valid")
    hit = np.flatnonzero(runs == length)
    return int(hit[0]) if hit.size else None


def _trial_divergence(out: MethodOutput, b: int) -> tuple[int, str] | None:
    """``(epoch, cause)`` of trial ``b``'s first divergence, or None."""
    found: list[tuple[int, str]] = []
    bad = ~np.isfinite(out.est[b]).all(axis=-1)
    if bad.any():
        found.append((int(np.argmax(bad)), "the estimate is not finite (NaN or inf)"))
    if out.var is not None:
        var = np.asarray(out.var[b])
        wrong = (np.isinf(var) | (var < 0.0)).any(axis=-1)
        if wrong.any():
            found.append((int(np.argmax(wrong)), "a variance is infinite or negative"))
    if out.nis is not None:
        for c, (block, rows) in enumerate(BLOCKS):
            nis = np.asarray(out.nis[b, :, c])
            updates = np.flatnonzero(np.isfinite(nis))
            i = _first_run(nis[updates] > NIS_IMPLAUSIBLE * rows, NIS_RUN)
            if i is not None:
                top = float(np.min(nis[updates[i : i + NIS_RUN]]) / rows)
                found.append(
                    (
                        int(updates[i]),
                        f"the {block} NIS/{rows} stays above {NIS_IMPLAUSIBLE:.0e} for "
                        f"{NIS_RUN} consecutive updates (at least {top:.3g}): the filter no "
                        "longer tracks the data",
                    )
                )
    if found:
        return min(found)
    if bool(np.asarray(out.diverged)[b]):
        return -1, "flagged as diverged by the method"
    return None


def find_divergences(
    method: str, out: MethodOutput, t: np.ndarray, trial_ids: np.ndarray
) -> list[Divergence]:
    """Every trial of ``out`` that diverged, at its first epoch (module doc); ``t`` (N,) the
    epochs' times, s; ``trial_ids`` (B,) the trials' ids."""
    res = []
    for b in range(out.est.shape[0]):
        hit = _trial_divergence(out, b)
        if hit is not None:
            epoch, cause = hit
            t_s = float(t[epoch]) if epoch >= 0 else float("nan")
            res.append(Divergence(method, int(trial_ids[b]), epoch, t_s, cause))
    return res


def divergence_lines(divs: Sequence[Divergence], names: Sequence[str] | None = None) -> list[str]:
    """summary.md's section on divergences (none: no lines); ``names[trial]``: what trial
    ``trial`` is (recorded data: its file)."""
    if not divs:
        return []
    lines = [
        DIVERGED_HEADING,
        "",
        f"**{len(divs)} run(s) diverged**: from the epoch named on, the method's numbers below "
        "(and in every file of this folder) describe a filter that no longer tracks the data "
        f'(docs/recorded_data.md, "Divergence"). The command exits with {EXIT_DIVERGED}.',
        "",
    ]
    for d in divs:
        where = None if names is None else names[d.trial]
        lines.append(f"- {d.describe(where)}")
    return [*lines, ""]
