"""Compile options shared by the compiled kernels (numba).

The numbers a compiled routine produces depend on its options as much as on its source: with
``fastmath`` LLVM may reassociate sums and fuse multiply–adds, so the same routine compiled with
other flags (or moved to a module that compiles it with other flags) can differ in the last
bits. Every routine of the transfer-alignment kernel and of its shared pieces (the compiled
rotation core :mod:`qkf.core.quat`, the compiled model
:mod:`qkf.transfer_alignment.model_compiled`) is therefore compiled through :func:`kernel_jit`,
and moving one between modules keeps its options.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba as nb

FASTMATH = {"reassoc", "contract", "arcp"}
"""LLVM fast-math flags of the kernels: reassociation lets LLVM vectorise the small reductions,
``contract`` fuses multiply–adds, ``arcp`` turns divisions into reciprocal multiplications.
NaN and Inf semantics are kept (no ``nnan``/``ninf``), so the finiteness checks still work."""

_F = TypeVar("_F", bound=Callable[..., Any])


def kernel_jit(*, inline: bool = False, nrt: bool = False) -> Callable[[_F], _F]:
    """``nb.njit`` for per-epoch code: cached, :data:`FASTMATH`, and by default without the NRT.

    Per-epoch code only reads and writes arrays allocated elsewhere, so it needs no reference
    counting; with the NRT, every array handed to a helper or taken from a named tuple costs an
    atomic incref/decref pair, and at ~100 of them per epoch the split filter kernel ran
    10-40 % slower than a monolithic one. ``nrt=True`` for code that allocates arrays.
    ``inline``: inline into the caller at the numba-IR level (the loops then see the caller's
    arrays). ``_nrt`` is a private numba option, hence the cast for the type checker.
    """
    options: dict[str, Any] = {"cache": True, "fastmath": FASTMATH}
    if not nrt:
        options["_nrt"] = False
    if inline:
        options["inline"] = "always"
    return cast("Callable[[_F], _F]", nb.njit(**options))
