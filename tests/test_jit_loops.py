"""The loops qkf.core.jit makes of one per-row routine: what they take, what they run, and that
the parallel and the serial compilation of one definition stay apart in numba's cache."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from qkf.core.jit import kernel_jit, parallel_and_serial, row_loops


@kernel_jit(nrt=True, cache=False)
def _scaled_sum(i: int, a: np.ndarray, scale: float, out: np.ndarray, work: np.ndarray) -> None:
    """``out[i] = scale Σ_j a[i, j]``, through the batch's scratch ``work`` (B,)."""
    work[i] = 0.0
    for j in range(a.shape[1]):
        work[i] += a[i, j]
    out[i] = scale * work[i]


@kernel_jit(nrt=True, cache=False)
def _work_for(a: np.ndarray) -> np.ndarray:
    return np.empty(a.shape[0])


def test_row_loops_run_every_row_with_the_scratch_made_once() -> None:
    loops = row_loops(_scaled_sum, "a.shape[0]", scratch=_work_for, cache=False)
    a = np.arange(12.0).reshape(4, 3)
    want = 0.5 * a.sum(axis=1)
    for loop in (loops.parallel, loops.serial):
        out = np.zeros(4)
        loop(a, 0.5, out)  # the routine's arguments after the index, less the scratch
        np.testing.assert_array_equal(out, want)
    one = np.zeros(4)
    loops.row(2, a, 0.5, one, np.empty(4))  # the per-row entry: the routine itself
    assert one[2] == want[2] and not one[[0, 1, 3]].any()


def test_the_parallel_and_serial_copies_have_their_own_cache_names() -> None:
    loops = row_loops(_scaled_sum, "a.shape[0]", scratch=_work_for, cache=False)
    names = {loops.parallel.py_func.__qualname__, loops.serial.py_func.__qualname__}  # type: ignore[attr-defined]
    assert names == {"_scaled_sum_rows", "_scaled_sum_rows_serial"}
    assert loops.parallel.targetoptions["parallel"]  # type: ignore[attr-defined]
    assert "parallel" not in loops.serial.targetoptions  # type: ignore[attr-defined]

    def total(x: np.ndarray) -> float:
        acc = 0.0
        for i in nb.prange(x.shape[0]):
            acc += x[i]
        return acc

    parallel, serial = parallel_and_serial(total, cache=False)
    assert parallel(np.ones(5)) == serial(np.ones(5)) == 5.0


def test_a_row_may_not_take_the_loops_own_names() -> None:
    @kernel_jit(cache=False)
    def clash(i: int, _row: np.ndarray) -> None:
        _row[i] = 0.0

    with pytest.raises(ValueError, match="a parameter is named"):
        row_loops(clash, "_row.shape[0]", cache=False)


def test_both_loops_and_a_direct_call_share_one_compilation_of_the_row() -> None:
    """A parallel loop's own index is unsigned; handed on as it is, the row routine (with
    everything it calls) would be compiled a second time for it."""

    @kernel_jit(cache=False)
    def double(i: int, x: np.ndarray) -> None:
        x[i] *= 2.0

    loops = row_loops(double, "x.shape[0]", cache=False)
    x = np.ones(3)
    loops.parallel(x)
    loops.serial(x)
    loops.row(0, x)
    np.testing.assert_array_equal(x, [8.0, 4.0, 4.0])
    assert [str(sig[0]) for sig in double.signatures] == ["int64"]  # type: ignore[attr-defined]
