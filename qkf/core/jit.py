"""Compile options shared by the compiled kernels (numba), and how compiled calls are bound.

The numbers a compiled routine produces depend on its options as much as on its source: with
``fastmath`` LLVM may reassociate sums and fuse multiply–adds, so the same routine compiled with
other flags (or moved to a module that compiles it with other flags) can differ in the last
bits. Every routine of the transfer-alignment kernel and of its shared pieces (the compiled
rotation core :mod:`qkf.core.quat`, the compiled model
:mod:`qkf.transfer_alignment.model_compiled`) is therefore compiled through :func:`kernel_jit`,
and moving one between modules keeps its options.

A batch runs one compiled per-row routine over its rows. :func:`row_loops` makes, from that one
routine, the loop that runs the rows in parallel (``nb.prange``), the one that runs them in the
calling thread (small batches: a parallel region costs more than it saves there) and keeps the
routine itself as the per-row entry; :func:`parallel_and_serial` compiles a hand-written loop
both ways. Each entry runs its own compiled copy of the routine, optimised in its own module
(:func:`internalize_linked_functions`), so two entries can round differently in the last bits
where LLVM fuses or reorders otherwise; where a caller needs them to agree to the bit, a test
checks it (the filter kernel's two paths: tests/test_env_single_vs_batched.py).

Importing this module also makes every compiled function run the code that was compiled with
it, whatever the state of numba's on-disk cache (:func:`bind_callee_copies_locally`;
docs/performance.md, "A fresh compile and the cached code"). Every module of ``qkf`` and
``envs`` that compiles code imports it before anything is compiled.
"""

from __future__ import annotations

import inspect
import os
import types
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar, cast

# OpenMP worker threads (numba's "omp" threading layer, GNU libgomp) spin for a while after
# each parallel region by default. Between two batched filter periods the main thread does the
# environment's numpy work and draws episodes, and the spinning workers took the second core
# from it: on 2 cores the batched gyro environment ran 40 % slower and the single
# transfer-alignment environment 25 % slower (docs/performance.md, "Threads that spin"). libgomp
# reads the setting when it is loaded, which numba does at its first parallel run, after this
# import. A value the user set is kept.
os.environ.setdefault("GOMP_SPINCOUNT", "0")

import llvmlite.binding as ll
import numba as nb
import numpy as np
from numba.core import codegen as _codegen

FASTMATH = {"reassoc", "contract", "arcp"}
"""LLVM fast-math flags of the kernels: reassociation lets LLVM vectorise the small reductions,
``contract`` fuses multiply–adds, ``arcp`` turns divisions into reciprocal multiplications.
NaN and Inf semantics are kept (no ``nnan``/``ninf``), so the finiteness checks still work."""

LINK_TAG = "qkf-local-callee-copies-2"
"""Appended to numba's cache key (the code generator's ``magic_tuple``) where
:func:`bind_callee_copies_locally` is installed: code cached without it (weakly bound copies) is
never loaded where it is installed, and the other way round."""

_F = TypeVar("_F", bound=Callable[..., Any])


def internalize_linked_functions(module: ll.ModuleRef, own: set[str] | None = None) -> int:
    """Give internal linkage to the copies of compiled callees that numba linked into an
    optimised ``module``; returns their number.

    The copies are the function definitions not in ``own`` (the names the library defined
    itself before numba linked its callees in), and any ``linkonce_odr`` definition (what
    numba links in; also its per-module helpers, such as ``NRT_incref``).

    numba links into the LLVM module of each compiled function a copy of every compiled function
    it calls, as ``linkonce_odr`` (the wrapper of a ``prange`` loop as ``weak_odr``), and
    optimises the whole module again. A copy that is not inlined stays a weak symbol of the
    object code, and the JIT linker binds every call to a weak symbol to the first definition of
    that name loaded into the process: the callee's own code if the process compiled it first
    (callees compile before their callers), or the copy inside whichever caller was loaded first
    from the cache. The copies are optimised in different modules and round differently, so
    results depended on what the process had compiled or loaded before. An internal copy is
    bound inside its own object code.
    """
    local = (ll.Linkage.internal, ll.Linkage.private)
    count = 0
    for fn in module.functions:
        if fn.is_declaration or fn.linkage in local:
            continue
        if fn.linkage == ll.Linkage.linkonce_odr or (own is not None and fn.name not in own):
            fn.linkage = ll.Linkage.internal
            count += 1
    return count


def bind_callee_copies_locally() -> None:
    """Make every function numba compiles from now on (in this process) call only the copies
    of its callees that were compiled into its own object code; idempotent.

    Runs :func:`internalize_linked_functions` after numba's optimisation of a library's final
    module and before its machine code is generated: the optimised code is the one numba makes
    without it, only the binding of the calls changes. The machine code numba caches is what
    the JIT ran, byte for byte, so a function gives the same numbers compiled in the running
    process, loaded from a cache one process wrote, or from one that several processes wrote
    at once. Adds :data:`LINK_TAG` to the cache key.
    """
    library_class = _codegen.CPUCodeLibrary
    if getattr(library_class, "_qkf_local_copies", False):
        return
    finalize = getattr(library_class, "finalize", None)
    optimize = getattr(library_class, "_optimize_final_module", None)
    magic_tuple = getattr(_codegen.CPUCodegen, "magic_tuple", None)
    if finalize is None or optimize is None or magic_tuple is None:  # pragma: no cover
        raise RuntimeError(
            f"numba {nb.__version__}: CPUCodeLibrary.finalize, ._optimize_final_module or "
            "CPUCodegen.magic_tuple is missing; qkf.core.jit cannot bind compiled callees "
            "locally (docs/performance.md)"
        )

    def _finalize(self: Any) -> None:
        # before numba links the callees in: what the library defines itself
        self._qkf_own = {f.name for f in self._final_module.functions if not f.is_declaration}
        finalize(self)

    def _optimize_final_module(self: Any) -> None:  # called by finalize, after the linking
        optimize(self)
        internalize_linked_functions(self._final_module, getattr(self, "_qkf_own", None))

    def _magic_tuple(self: Any) -> tuple[Any, ...]:
        return (*magic_tuple(self), LINK_TAG)

    library_class.finalize = _finalize  # type: ignore[method-assign]
    library_class._optimize_final_module = _optimize_final_module  # type: ignore[method-assign]
    _codegen.CPUCodegen.magic_tuple = _magic_tuple  # type: ignore[method-assign]
    library_class._qkf_local_copies = True  # type: ignore[attr-defined]


bind_callee_copies_locally()


def kernel_jit(
    *,
    inline: bool = False,
    nrt: bool = False,
    parallel: bool = False,
    fastmath: bool = True,
    cache: bool = True,
) -> Callable[[_F], _F]:
    """``nb.njit`` for per-epoch code: cached, :data:`FASTMATH`, and by default without the NRT.

    Per-epoch code only reads and writes arrays allocated elsewhere, so it needs no reference
    counting; with the NRT, every array handed to a helper or taken from a named tuple costs an
    atomic incref/decref pair, and at ~100 of them per epoch the split filter kernel ran
    10-40 % slower than a monolithic one. ``nrt=True`` for code that allocates arrays.
    ``inline``: inline into the caller at the numba-IR level (the loops then see the caller's
    arrays). ``_nrt`` is a private numba option, hence the cast for the type checker.
    ``parallel``: ``nb.prange`` loops run on numba's threads (prefer :func:`row_loops`).
    ``fastmath=False``: strict IEEE arithmetic, for code held to a reference that rounds that
    way (the gyro UKF, to filterpy). ``cache=False`` for code compiled outside ``qkf`` (tests):
    numba checks a cache entry against its own source file only, and such code would keep stale
    copies of the ``qkf`` routines it calls (:mod:`qkf.core.numba_cache` covers ``qkf`` only).
    """
    options: dict[str, Any] = {"cache": cache}
    if fastmath:
        options["fastmath"] = FASTMATH
    if not nrt:
        options["_nrt"] = False
    if inline:
        options["inline"] = "always"
    if parallel:
        options["parallel"] = True
    return cast("Callable[[_F], _F]", nb.njit(**options))


def parallel_and_serial(loop: _F, *, fastmath: bool = True, cache: bool = True) -> tuple[_F, _F]:
    """``loop`` compiled twice (with the NRT, see :func:`kernel_jit`): its ``nb.prange`` loops run
    on numba's threads in the first and in the calling thread in the second.

    One definition serves both, so they cannot drift apart. The serial copy is the same Python
    function under the name ``<name>_serial``: numba's cache key holds the source and the
    argument types but not the compile options, so under one name the two would load each
    other's code from the cache.
    """
    serial = types.FunctionType(
        loop.__code__, loop.__globals__, loop.__name__, loop.__defaults__, loop.__closure__
    )
    serial.__qualname__ = f"{loop.__qualname__}_serial"
    serial.__module__ = loop.__module__
    serial.__doc__ = loop.__doc__
    serial.__annotations__ = loop.__annotations__
    serial.__kwdefaults__ = loop.__kwdefaults__
    compile_as = {"nrt": True, "fastmath": fastmath, "cache": cache}
    return (
        kernel_jit(parallel=True, **compile_as)(loop),
        cast("_F", kernel_jit(**compile_as)(serial)),
    )


SERIAL_BELOW = 4
"""Batches of fewer rows run a row loop's serial entry (:meth:`RowLoops.for_rows`; the filter
kernel and the VB epoch choose the same way): for a batch of one or two a parallel region only
costs, its threads started and joined every call and waiting for cores whenever other
processes hold them (docs/performance.md). A process that runs small batches only never
compiles the parallel loop either, which costs more than the serial one: 2–20 s of LLVM
beyond the per-row routine (``benchmarks/compile_census.py``)."""


class RowLoops(NamedTuple):
    """The entry points :func:`row_loops` makes of one per-row routine ``row(i, *args)``."""

    parallel: Callable[..., None]  # (*args): every row, rows on numba's threads
    serial: Callable[..., None]  # (*args): every row, in order, in the calling thread
    row: Callable[..., None]  # (i, *args): row i alone, the routine itself

    def for_rows(self, n: int) -> Callable[..., None]:
        """The loop for a batch of ``n`` rows: serial below :data:`SERIAL_BELOW`, else
        parallel."""
        return self.serial if n < SERIAL_BELOW else self.parallel


def _parameters(dispatcher: Callable[..., Any]) -> list[str]:
    """The parameter names of the Python function a numba dispatcher compiles."""
    return list(inspect.signature(dispatcher.py_func).parameters)  # type: ignore[attr-defined]


_LOOP_NAMES = frozenset({"_row", "_prange", "_i", "_int64", "_scratch", "_work"})
"""The names the generated loop uses itself; a per-row routine must not take them."""


def row_loops(
    row: Callable[..., None],
    rows: str,
    *,
    scratch: Callable[..., Any] | None = None,
    fastmath: bool = True,
    cache: bool = True,
) -> RowLoops:
    """The loops over a batch of the compiled per-row routine ``row(i, *args)``.

    ``rows`` is the number of rows, an expression of ``row``'s arguments after the index (for
    example ``"x.shape[0]"``). The loops take those arguments and run
    ``for i in prange(rows): row(i, *args)``, compiled by :func:`parallel_and_serial` (its
    flags: ``fastmath``, ``cache``). The index reaches ``row`` as an ``int64`` in both loops:
    a parallel loop's own index is unsigned, and ``row`` (with everything it calls) would
    otherwise be compiled twice, once per index type (for the transfer-alignment kernel, about
    a quarter of a cold compile). Named tuples of arrays pass as they do into a hand-written
    loop; the prange body is the single call on purpose (inside a parfor numba drops writes to
    arrays reached through named-tuple attributes, numba#5872).

    ``scratch``: a compiled routine that allocates the work arrays of the whole batch, once per
    call of a loop; its parameters are named after arguments of ``row``, and what it returns (an
    array or a plain tuple of arrays: a named tuple made outside a parfor cannot enter it,
    numba#5299) goes to ``row``'s last parameter, which the loops then do not take.

    The loop is generated with ``row``'s own parameter names and placed at ``row``'s own lines
    of its file: numba caches it next to that file and checks the cache against it, as it
    would a loop written there, and its messages point at the per-row routine.
    """
    py_func = row.py_func  # type: ignore[attr-defined]  # a numba dispatcher
    params = _parameters(row)[1:]
    if _LOOP_NAMES & set(params):
        raise ValueError(f"{py_func.__qualname__}: a parameter is named {sorted(_LOOP_NAMES)}")
    taken = params if scratch is None else params[:-1]
    passed = taken if scratch is None else [*taken, "_work"]
    lines = [f"def {py_func.__name__}_rows({', '.join(taken)}):"]
    if scratch is not None:
        lines.append(f"    _work = _scratch({', '.join(_parameters(scratch))})")
    lines += [
        f"    for _i in _prange({rows}):",
        f"        _row(_int64(_i), {', '.join(passed)})",
    ]
    code = py_func.__code__
    source = "\n" * (code.co_firstlineno - 1) + "\n".join(lines) + "\n"
    scope: dict[str, Any] = {
        "_prange": nb.prange,
        "_row": row,
        "_scratch": scratch,
        "_int64": np.int64,
    }
    exec(compile(source, code.co_filename, "exec"), scope)
    loop = scope[f"{py_func.__name__}_rows"]
    loop.__module__ = py_func.__module__
    loop.__qualname__ = f"{py_func.__qualname__}_rows"
    loop.__doc__ = f"{py_func.__qualname__} for every row of a batch ({rows} rows)."
    parallel, serial = parallel_and_serial(loop, fastmath=fastmath, cache=cache)
    return RowLoops(parallel, serial, row)


def kernel_array(arr: Any, dtype: type, shape: tuple[int, ...]) -> np.ndarray:
    """``arr`` broadcast to ``shape`` as a writable C-contiguous array of ``dtype``: copied
    unless it is one already.

    A compiled routine is specialised on the type of each array it takes, the read-only flag
    and the layout included. A read-only view (a broadcast, even one that is contiguous, such as
    one trial's (n,) mask as (1, n)) therefore compiles a second copy of every routine it
    reaches: the filter kernel took 13 s of LLVM per copy, and a process that ran one trial
    and then a batch compiled it twice.
    """
    out: np.ndarray = np.asarray(arr, dtype=dtype)
    if out.shape == shape:
        if out.flags.c_contiguous and out.flags.writeable:
            return out
        return np.array(out, order="C")
    if out.ndim > len(shape):  # assignment would drop leading axes of length 1
        raise ValueError(f"an array of shape {out.shape} cannot be broadcast to {shape}")
    # np.broadcast_to costs ten times the copy at an environment step's sizes: assign instead
    full: np.ndarray = np.empty(shape, dtype=dtype)
    full[...] = out  # broadcasts, or raises ValueError naming both shapes
    return full
