"""Small dense products and the SPD inverse of the batch estimator (compiled).

Sizes are read at run time: constant trip counts would let LLVM unroll every loop nest in full,
which made the estimator take minutes to compile. ``out`` never aliases an input. Inner loops
run along rows (axpy form), which vectorises.
"""

from __future__ import annotations

import numpy as np

from qkf.core.jit import kernel_jit
from qkf.core.kalman import backward_solve_t, cholesky_inplace, forward_solve


@kernel_jit(nrt=True)
def mm(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a b``."""
    out[:] = 0.0
    mm_add(a, b, out)


@kernel_jit(nrt=True)
def mm_add(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out += a b``."""
    for i in range(a.shape[0]):
        for c in range(a.shape[1]):
            aic = a[i, c]
            if aic != 0.0:
                for j in range(b.shape[1]):
                    out[i, j] += aic * b[c, j]


@kernel_jit(nrt=True)
def tm_add(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out += aᵀ b``."""
    for c in range(a.shape[0]):
        for i in range(a.shape[1]):
            aci = a[c, i]
            if aci != 0.0:
                for j in range(b.shape[1]):
                    out[i, j] += aci * b[c, j]


@kernel_jit(nrt=True)
def mt(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a bᵀ``."""
    for i in range(a.shape[0]):
        for j in range(b.shape[0]):
            v = 0.0
            for c in range(a.shape[1]):
                v += a[i, c] * b[j, c]
            out[i, j] = v


@kernel_jit(nrt=True)
def inverse_spd(mat: np.ndarray, out: np.ndarray) -> bool:
    """``out = mat⁻¹`` of a symmetric positive-definite matrix (``mat`` is overwritten by its
    Cholesky factor); False if it is not positive definite."""
    n = mat.shape[0]
    if not cholesky_inplace(mat):
        return False
    col = np.empty(n)
    for j in range(n):
        col[:] = 0.0
        col[j] = 1.0
        forward_solve(mat, col)
        backward_solve_t(mat, col)
        for i in range(n):
            out[i, j] = col[i]
    return True
