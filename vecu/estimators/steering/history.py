"""The recorded forward pass of a steering filter: one float64 row per step in a ring.

Row k: x_k|k, P_k|k (10 upper-triangle entries), x_k|k-1, P_k|k-1, C_k = cov(x_k-1|k-1, x_k|k-1)
(16, row-major), the v_x of the predict, G_k = C_k+1 P_k+1|k^-1 (16; written with row k+1 by
steering.rts). Rows at `head` (mod capacity), the oldest dropped first; maxlen None grows.
"""

from __future__ import annotations

import numpy as np

from vecu.estimators.steering.base import FilterRun

COL_X, COL_P, COL_XP, COL_PP, COL_C, COL_VX, COL_G = 0, 4, 14, 18, 28, 44, 45
N_COLS = 61
UNBOUNDED_START = 256  # initial rows of an unbounded ring (doubled when full)
# column offsets of P's 16 entries (row-major) in the 10-entry upper triangle
IDX16 = np.array([0, 1, 2, 3, 1, 4, 5, 6, 2, 5, 7, 8, 3, 6, 8, 9])
TRIU = np.triu_indices(4)


class Ring:
    """The recorded steps as rows of a float64 array `hist` (module docstring)."""

    __slots__ = ("count", "head", "hist", "maxlen")

    def __init__(self, maxlen: int | None, rows: np.ndarray | None = None) -> None:
        self.maxlen = maxlen
        n = 0 if rows is None else rows.shape[0]
        cap = maxlen if maxlen is not None else max(UNBOUNDED_START, 2 * n)
        self.hist = np.zeros((max(cap, 1), N_COLS))
        if rows is not None and n:
            rows = rows[-cap:]
            n = rows.shape[0]
            self.hist[:n] = rows
        self.count = n
        self.head = n % self.hist.shape[0]

    def slot(self) -> int:
        """The row the next step writes (grows an unbounded ring first if it is full)."""
        cap = self.hist.shape[0]
        if self.maxlen is None and self.count == cap:
            self.hist = np.concatenate([self.hist, np.zeros((cap, N_COLS))])
            self.head = cap
        return self.head

    def advance(self) -> None:
        """The row at `head` is complete: count it."""
        cap = self.hist.shape[0]
        self.head = (self.head + 1) % cap
        if self.count < cap:
            self.count += 1

    def newest(self) -> int:
        return (self.head - 1) % self.hist.shape[0]

    def ordered(self) -> np.ndarray:
        """Copy of the rows, oldest first."""
        cap = self.hist.shape[0]
        idx = (self.head - self.count + np.arange(self.count)) % cap
        return self.hist[idx]

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(x, P, x_pred, P_pred, C, v_x) over the rows, oldest first (a FilterRun's fields)."""
        rows = self.ordered()
        return (rows[:, COL_X:COL_P].copy(), rows[:, COL_P + IDX16].reshape(-1, 4, 4),
                rows[:, COL_XP:COL_PP].copy(), rows[:, COL_PP + IDX16].reshape(-1, 4, 4),
                rows[:, COL_C:COL_VX].reshape(-1, 4, 4), rows[:, COL_VX].copy())

    def vx(self) -> list[float]:
        """v_x of the rows, oldest first."""
        return self.ordered()[:, COL_VX].tolist()

    def oldest_vx(self) -> float:
        return float(self.hist[(self.head - self.count) % self.hist.shape[0], COL_VX])


def rows_from_run(run: FilterRun) -> np.ndarray:
    """Ring rows (no gains) of a recorded forward pass: the inverse of Ring.arrays."""
    n = run.x.shape[0]
    rows = np.zeros((n, N_COLS))
    rows[:, COL_X:COL_P] = run.x
    rows[:, COL_P:COL_XP] = run.P[:, TRIU[0], TRIU[1]]
    rows[:, COL_XP:COL_PP] = run.x_pred
    rows[:, COL_PP:COL_C] = run.P_pred[:, TRIU[0], TRIU[1]]
    rows[:, COL_C:COL_VX] = run.C.reshape(n, 16)
    rows[:, COL_VX] = run.v_x
    return rows
