"""The loops qkf.core.jit makes of one per-row routine: what they take, what they run, and that
the parallel and the serial compilation of one definition stay apart in numba's cache."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from qkf.core.jit import SERIAL_BELOW, kernel_array, kernel_jit, parallel_and_serial, row_loops


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


def test_small_batches_take_the_serial_loop() -> None:
    loops = row_loops(_scaled_sum, "a.shape[0]", scratch=_work_for, cache=False)
    assert [loops.for_rows(n) is loops.serial for n in (1, SERIAL_BELOW - 1)] == [True, True]
    assert [loops.for_rows(n) is loops.parallel for n in (SERIAL_BELOW, 64)] == [True, True]


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


def test_kernel_array_hands_the_kernels_one_array_type() -> None:
    """Writable and C-contiguous whatever it is given (copied only when it is not already), so
    that a compiled routine is not compiled again for a read-only or strided view."""
    one_trial = kernel_array(np.array([True, False, True]), bool, (1, 3))
    assert one_trial.flags.writeable and one_trial.flags.c_contiguous  # a (1, n) broadcast is
    np.testing.assert_array_equal(one_trial, [[True, False, True]])  # contiguous, read-only
    view = np.broadcast_to(np.eye(2, 3, dtype=bool), (2, 3))
    assert not view.flags.writeable
    got = kernel_array(view, bool, (2, 3))
    assert got.flags.writeable and got is not view
    np.testing.assert_array_equal(got, view)
    strided = kernel_array(np.arange(12.0).reshape(2, 6)[:, ::2], float, (2, 3))
    assert strided.flags.c_contiguous
    np.testing.assert_array_equal(strided, [[0.0, 2.0, 4.0], [6.0, 8.0, 10.0]])
    fine = np.ones((2, 3), dtype=bool)
    assert kernel_array(fine, bool, (2, 3)) is fine  # nothing to copy
    for wrong in (np.ones(4), np.ones((1, 2, 3))):  # as np.broadcast_to refuses them
        with pytest.raises(ValueError, match="broadcast"):
            kernel_array(wrong, float, (2, 3))


def test_the_filter_kernel_gets_a_writable_mask_from_every_caller(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """One trial (the single environment: an (n,) mask broadcast to (1, n) is read-only, yet
    contiguous), a read-only (B, n) mask and a writable one reach the kernel as the same array
    type; before, the first two compiled the kernel a second time (13 s of LLVM each)."""
    from qkf.transfer_alignment import kernel
    from qkf.transfer_alignment.config import load_config
    from qkf.transfer_alignment.filter import FilterParams, TransferAlignmentKF

    seen: list[np.ndarray] = []
    monkeypatch.setattr(kernel, "run_block", lambda st, inp, c, rec: seen.append(inp.has_meas))
    monkeypatch.setattr(kernel, "run_block_serial", lambda st, inp, c, rec: seen.append(inp[3]))
    params = FilterParams.from_config(load_config("paper"))
    n = 3
    for b, mask in (
        (1, np.array([True, False, True])),
        (SERIAL_BELOW, np.broadcast_to(np.array([True, False, True]), (4, n))),
        (SERIAL_BELOW, np.ones((4, n), dtype=bool)),
    ):
        kf = TransferAlignmentKF(params, b)
        kf.step(np.zeros((b, n, 3)), np.zeros((b, n, 4)), np.zeros((b, n, 3)), mask)
    assert [(m.shape, m.flags.writeable, m.flags.c_contiguous) for m in seen] == [
        ((1, n), True, True),
        ((4, n), True, True),
        ((4, n), True, True),
    ]


def _arrays_seen(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list[np.ndarray]:
    """The array arguments of every call of ``module.name`` (replaced by a recorder)."""
    seen: list[np.ndarray] = []
    monkeypatch.setattr(
        module, name, lambda *args: seen.extend(a for a in args if isinstance(a, np.ndarray))
    )
    return seen


def _one_type(arrays: list[np.ndarray]) -> bool:
    return bool(arrays) and all(a.flags.writeable and a.flags.c_contiguous for a in arrays)


def test_the_numpy_facing_routines_pass_their_compiled_code_one_array_type(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Strided columns, broadcasts and read-only views (what the filter's records, one trial's
    truth and the environments' shared masks are) reach the compiled code as writable
    C-contiguous arrays, so each routine compiles once (it compiled up to seven times in the
    test suite)."""
    from envs.transfer_alignment import period_summary as ps
    from qkf.core import quat
    from qkf.transfer_alignment import filter as flt
    from qkf.transfer_alignment import metrics

    rng = np.random.default_rng(0)
    b, n = 2, 5
    stats = rng.normal(size=(b, n, 5))
    est = rng.normal(size=(b, n, 16))
    frozen = np.ones((b, n), dtype=bool)
    frozen.flags.writeable = False
    record = flt.FilterRecord(
        est=est[:, :, :],
        var=np.abs(rng.normal(size=(b, n, 15))),
        cov=None,
        dx=np.zeros((b, n, 15)),
        innov=np.zeros((b, n, 6)),
        nis_att=stats[..., 0],
        nis_rate=stats[..., 1],
        nis=stats[..., 2],
        logdet_s=stats[..., 3],
        trace_s_att=stats[..., 4],
        rate=rng.normal(size=(b, n, 3)),
    )
    seen = _arrays_seen(monkeypatch, metrics, "_state_errors_into")
    metrics.state_errors(est[:, :, :], est[0, :, :4], est[:, :, 4:7], est[:, :, 7:])
    assert _one_type(seen)
    seen = _arrays_seen(monkeypatch, flt, "_loglik_into")
    assert record.loglik.shape == (b, n)
    assert _one_type(seen)
    seen = _arrays_seen(monkeypatch, ps, "_summarise")
    ps.period_summary(record, frozen, np.full(b, n - 1), np.ones(15), np.array([[0, 3]]))
    assert _one_type(seen)
    seen = _arrays_seen(monkeypatch, quat, "attitude_error_into")
    quat.attitude_error(np.broadcast_to(est[0, 0, :4], (n, 4)), est[1, :, :4])
    assert _one_type(seen)
