"""Numerical guards shared by every filter in vecu: `symmetrise`, `cholesky_lower` (never fails on
a finite P: jitter, then eigenvalue clipping), `diverged` (the reset criterion; filters reset to
their prior and count it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vecu.kernels import kernel

# Relative jitter tried before eigenvalue clipping: eps * scale * 10**k, k = 0..JITTER_STEPS-1.
JITTER_STEPS = 6
JITTER_REL = 1e-12
EIG_FLOOR_REL = 1e-12


@dataclass(frozen=True)
class DivergenceBounds:
    """Limits beyond which a filter is considered diverged (and reset)."""

    max_trace: float = 1e6
    max_abs_state: float = 1e6


def symmetrise(P: np.ndarray) -> np.ndarray:
    """(P + P^T) / 2."""
    return 0.5 * (P + P.T)


def _scale(P: np.ndarray) -> float:
    d = np.abs(np.diag(P))
    s = float(d.max()) if d.size else 0.0
    return s if s > 0.0 else 1.0


def clip_eigenvalues(P: np.ndarray, floor_rel: float = EIG_FLOOR_REL) -> np.ndarray:
    """Nearest-ish SPD matrix: eigenvalues raised to floor_rel * max(|eig|, 1e-300)."""
    vals, vecs = np.linalg.eigh(symmetrise(P))
    floor = floor_rel * max(float(np.abs(vals).max()), 1e-300)
    vals = np.maximum(vals, floor)
    return symmetrise((vecs * vals) @ vecs.T)


def cholesky_lower(P: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of P with fallbacks; raises ValueError only for a non-finite P.

    Order: plain Cholesky of the lower triangle (as LAPACK reads it); then of symmetrise(P) plus
    jitter eps*scale*10^k on the diagonal; then of the eigenvalue-clipped matrix.
    """
    if not np.all(np.isfinite(P)):
        raise ValueError("covariance is not finite")
    try:
        return np.linalg.cholesky(P)
    except np.linalg.LinAlgError:
        pass
    Ps = symmetrise(P)
    scale = _scale(Ps)
    eye = np.eye(P.shape[0])
    for k in range(JITTER_STEPS):
        try:
            return np.linalg.cholesky(Ps + (JITTER_REL * scale * 10.0**k) * eye)
        except np.linalg.LinAlgError:
            continue
    Pc = clip_eigenvalues(Ps)
    try:
        return np.linalg.cholesky(Pc)
    except np.linalg.LinAlgError:
        # Clipped matrix still not numerically PD (extreme condition number): use the
        # eigen-decomposition root made triangular via QR, S = R^T with R from qr(sqrt(D) V^T).
        vals, vecs = np.linalg.eigh(Pc)
        root = vecs * np.sqrt(np.maximum(vals, 0.0))
        r = np.linalg.qr(root.T, mode="r")
        return np.asarray(r).T


def diverged(x: np.ndarray, P: np.ndarray, bounds: DivergenceBounds = DivergenceBounds()) -> bool:
    """True if x or P is non-finite, trace(P) > max_trace, trace(P) < 0 or |x| > max_abs_state."""
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        return True
    tr = float(np.trace(P))
    if tr > bounds.max_trace or tr < 0.0:
        return True
    return bool(np.abs(x).max() > bounds.max_abs_state) if x.size else False


@kernel(small=True)
def diverged_scalars(x: Sequence[float], trace: float, offdiag_sum: float, max_trace: float,
                     max_abs_state: float) -> bool:
    """The criterion of `diverged_floats` with the bounds as numbers (a kernel: compiled filter
    steps call it; x a tuple there)."""
    if not 0.0 <= trace <= max_trace:
        return True
    m = max_abs_state
    for v in x:
        if not -m <= v <= m:
            return True
    return offdiag_sum - offdiag_sum != 0.0


def diverged_floats(
    x: Sequence[float], trace: float, offdiag_sum: float,
    bounds: DivergenceBounds = DivergenceBounds(),
) -> bool:
    """Same criterion as `diverged` for filters holding plain floats (no numpy in their step).

    x: the state entries; trace: trace(P), so a NaN or inf on the diagonal fails the range test;
    offdiag_sum: the sum of the stored off-diagonal entries (NaN or +-inf makes `s - s` non-zero).
    """
    return diverged_scalars(x, trace, offdiag_sum, bounds.max_trace, bounds.max_abs_state)
