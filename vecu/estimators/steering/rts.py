"""The unscented RTS recursion over a steering filter's recorded forward pass (steering.history),
as kernels: the standard smoother (Saerkkae 2008) that Khalid et al.'s garbled eqs. (27)-(28)
describe (docs/models.md, "Steering › Smoothers"). `smoother_gain` G_k = C_k+1 P_k+1|k^-1,
`backward_pass` x_k|T = x_k|k + G_k (x_k+1|T - x_k+1|k); `solve4` is LAPACK dgesv.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vecu.estimators.steering.history import (
    COL_C,
    COL_G,
    COL_P,
    COL_PP,
    COL_VX,
    COL_X,
    COL_XP,
    N_COLS,
)
from vecu.kernels import kernel

NO_OUT = np.empty((0, 4))  # record: no output rows wanted
_DGESV_SYMBOL = "vecu_steering_dgesv"
_linked = _prepared = False


def solve4(a: Any, b: Any, iw: Any) -> int:
    """LAPACK dgesv for a 4x4 system with 4 right-hand sides, in place: a (4, 4) column-major,
    b the 16 entries of B column-major (overwritten with X = A^-1 B), iw int32 scratch
    [n, nrhs, lda, ldb, info, ipiv x 4]; returns info (> 0: singular). Compiled: `prepare`."""
    try:
        x = np.linalg.solve(a.T, b.reshape(4, 4).T)
    except np.linalg.LinAlgError:
        return 1
    b[:] = x.T.ravel()
    return 0


def _link_dgesv() -> None:
    """Before the first compilation or cache load of a kernel here (their `setup`): make
    `solve4` a call of LAPACK dgesv, by symbol name so that numba's disk cache stays valid
    across processes."""
    global _linked
    if _linked:
        return
    import llvmlite.binding as llvm
    from numba import types
    from numba.extending import get_cython_function_address, overload

    llvm.add_symbol(_DGESV_SYMBOL, get_cython_function_address("scipy.linalg.cython_lapack",
                                                               "dgesv"))
    ptr = types.voidptr
    dgesv = types.ExternalFunction(_DGESV_SYMBOL, types.void(ptr, ptr, ptr, ptr, ptr, ptr, ptr,
                                                             ptr))

    def solve4_lapack(a, b, iw):  # no annotations: numba compares them with the typer's
        # dgesv(n, nrhs, a, lda, ipiv, b, ldb, info)
        dgesv(iw[0:].ctypes, iw[1:].ctypes, a.ctypes, iw[2:].ctypes, iw[5:].ctypes, b.ctypes,
              iw[3:].ctypes, iw[4:].ctypes)
        return iw[4]

    overload(solve4)(lambda a, b, iw: solve4_lapack)
    _linked = True


@kernel(setup=_link_dgesv)
def smoother_gain(hist: Any, slot: int, prev: int) -> None:
    """G = C P_pred^-1 from row slot into row prev's gain columns: G^T = P_pred^-1 C^T (P_pred
    symmetric, so its row-major entries are its column-major ones; C row-major is C^T
    column-major and the solution X = G^T column-major is G row-major). Singular P_pred (it
    holds Q, so never in a run): LinAlgError."""
    a = np.empty((4, 4))
    k = COL_PP
    for i in range(4):
        for j in range(i, 4):
            a[i, j] = hist[slot, k]
            a[j, i] = hist[slot, k]
            k += 1
    b = np.empty(16)
    for i in range(16):
        b[i] = hist[slot, COL_C + i]
    iw = np.zeros(9, dtype=np.int32)
    iw[0] = iw[1] = iw[2] = iw[3] = 4
    if solve4(a, b, iw) != 0:
        raise np.linalg.LinAlgError("Singular matrix")
    for i in range(16):
        hist[prev, COL_G + i] = b[i]


@kernel
def backward_pass(hist: Any, newest: int, n: int, out: Any) -> tuple[float, float, float, float]:
    """x_k|T over the n rows ending at `newest` (ring order), from x_newest|newest: returns the
    oldest smoothed mean and, if out has n rows, writes all of them there, oldest first."""
    cap = hist.shape[0]
    write = out.shape[0] == n
    i = newest
    m0, m1, m2, m3 = hist[i, 0], hist[i, 1], hist[i, 2], hist[i, 3]
    if write:
        out[n - 1, 0], out[n - 1, 1], out[n - 1, 2], out[n - 1, 3] = m0, m1, m2, m3
    for t in range(n - 2, -1, -1):
        nxt = i
        i = i - 1 if i > 0 else cap - 1
        e0 = m0 - hist[nxt, COL_XP]
        e1 = m1 - hist[nxt, COL_XP + 1]
        e2 = m2 - hist[nxt, COL_XP + 2]
        e3 = m3 - hist[nxt, COL_XP + 3]
        g = COL_G
        m0 = (hist[i, 0] + hist[i, g] * e0 + hist[i, g + 1] * e1 + hist[i, g + 2] * e2
              + hist[i, g + 3] * e3)
        m1 = (hist[i, 1] + hist[i, g + 4] * e0 + hist[i, g + 5] * e1 + hist[i, g + 6] * e2
              + hist[i, g + 7] * e3)
        m2 = (hist[i, 2] + hist[i, g + 8] * e0 + hist[i, g + 9] * e1 + hist[i, g + 10] * e2
              + hist[i, g + 11] * e3)
        m3 = (hist[i, 3] + hist[i, g + 12] * e0 + hist[i, g + 13] * e1 + hist[i, g + 14] * e2
              + hist[i, g + 15] * e3)
        if write:
            out[t, 0], out[t, 1], out[t, 2], out[t, 3] = m0, m1, m2, m3
    return m0, m1, m2, m3


@kernel(setup=_link_dgesv)
def record(hist: Any, slot: int, prev: int, x: Any, p: Any, vx: float, n_back: int,
           out: Any) -> tuple[float, float, float, float]:
    """Write x, P, v_x into hist[slot]; if prev >= 0 the gain of row prev from this row's
    P_pred and C; if n_back > 0 the backward pass over the n_back rows ending here (its oldest
    mean is returned, all of them written to out if it has n_back rows)."""
    for i in range(4):
        hist[slot, COL_X + i] = x[i]
    for i in range(10):
        hist[slot, COL_P + i] = p[i]
    hist[slot, COL_VX] = vx
    if prev >= 0:
        smoother_gain(hist, slot, prev)
    if n_back > 0:
        return backward_pass(hist, slot, n_back, out)
    return 0.0, 0.0, 0.0, 0.0


@kernel(setup=_link_dgesv)
def smooth_window(hist: Any, newest: int, n: int, out: Any) -> None:
    """All n smoothed means of the window ending at `newest` into out (n, 4), oldest first."""
    backward_pass(hist, newest, n, out)


@kernel(setup=_link_dgesv)
def smooth_run(hist: Any, n: int, out: Any) -> None:
    """A whole recorded run in rows 0..n-1 (in order): every gain, then every smoothed mean
    into out (n, 4)."""
    for k in range(1, n):
        smoother_gain(hist, k, k - 1)
    backward_pass(hist, n - 1, n, out)


def prepare() -> None:
    """Once: run every kernel here on a small window now (compiled or loaded from numba's disk
    cache under numba), so that none compiles in the middle of a live run."""
    global _prepared
    if _prepared:
        return
    _prepared = True
    x, p = (0.0,) * 4, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0)
    hist = np.zeros((2, N_COLS))
    hist[:, COL_PP + np.array([0, 4, 7, 9])] = 1.0
    record(hist, 1, 0, x, p, 10.0, 2, NO_OUT)
    smooth_window(hist, 1, 2, np.empty((2, 4)))
    smooth_run(hist, 2, np.empty((2, 4)))
