"""The three sigma sets of Vargas et al. (2015), Section II-A, as fixed patterns: chi_j = x_hat +
S Z[:, j], S = chol(P), one weight vector w for mean and covariance (Step 3), column 0 the
paper's chi_0; sum w = 1, sum_j w_j Z_j = 0, sum_j w_j Z_j Z_j^T = I (`moment_errors`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class SigmaSet:
    """A sigma pattern Z (n x (N+1)) and its weights w (N+1); column 0 is chi_0."""

    name: str
    Z: np.ndarray
    w: np.ndarray

    @property
    def n(self) -> int:
        return int(self.Z.shape[0])

    @property
    def points(self) -> int:
        return int(self.Z.shape[1])


def _sym_sqrt(a: np.ndarray) -> np.ndarray:
    """Symmetric (principal) square root of a symmetric positive-definite matrix."""
    vals, vecs = np.linalg.eigh(a)
    if np.any(vals <= 0.0):
        raise ValueError("matrix is not positive definite")
    return (vecs * np.sqrt(vals)) @ vecs.T


def _frozen(name: str, Z: np.ndarray, w: np.ndarray) -> SigmaSet:
    Z = np.array(Z, dtype=float)
    w = np.array(w, dtype=float)
    Z.setflags(write=False)
    w.setflags(write=False)
    return SigmaSet(name=name, Z=Z, w=w)


def ahsm(n: int = 3, lam: float = 12.0) -> SigmaSet:
    """Additive Homogeneous Symmetric Minimum set, Steps 1-2 (2n+1 points).

    w0 = lam/(n+lam), w_i = w_{i+n} = 1/(2(n+lam)); chi_{i, i+n} = x_hat +- (sqrt((n+lam) P))_{*i},
    i.e. Z = [0, sqrt(n+lam) I, -sqrt(n+lam) I]. The paper uses lam = 12 (Section III-C): w0 = 0.8.
    """
    if lam == -n:
        raise ValueError("lambda must differ from -n (Step 1)")
    c = np.sqrt(n + lam)
    Z = np.hstack([np.zeros((n, 1)), c * np.eye(n), -c * np.eye(n)])
    w = np.full(2 * n + 1, 1.0 / (2.0 * (n + lam)))
    w[0] = lam / (n + lam)
    return _frozen("ahsm", Z, w)


def arm(n: int = 3, w0: float = 0.8) -> SigmaSet:
    """Additive Rho Minimum set, Step 1a and eq. (1) (n+1 points).

    rho = sqrt((1-w0)/n), C = symmetric root of I - rho^2 11^T,
    w_i = (w0 rho^2 C^-1 11^T C^-T)_ii (Step 1a; equals (1-w0)/n), W = diag(w_1..w_n);
    eq. (1): chi_0 = x_hat - S [rho]_{n x 1} / sqrt(w0), chi_i = x_hat + (S C W^-1/2)_{*i}.
    The paper does not give w0; we use 0.8 (= the AHSM centre weight, docs/models.md).
    """
    if not 0.0 < w0 < 1.0:
        raise ValueError("ARM needs 0 < w0 < 1 (Step 1a)")
    rho = np.sqrt((1.0 - w0) / n)
    ones = np.ones((n, n))
    C = _sym_sqrt(np.eye(n) - rho**2 * ones)
    Cinv = np.linalg.inv(C)
    wi = np.diag(w0 * rho**2 * Cinv @ ones @ Cinv.T).copy()
    Z0 = -np.full((n, 1), rho) / np.sqrt(w0)
    Zi = C @ np.diag(1.0 / np.sqrt(wi))
    return _frozen("arm", np.hstack([Z0, Zi]), np.concatenate([[w0], wi]))


def agm(v: tuple[float, ...] = (1.0, 1.0, 1.0)) -> SigmaSet:
    """Additive General Minimum set, Steps 1b-2b (n+1 points).

    w0 = 1/(1 + sum v_i^2), w_i = w0 v_i^2; E = sqrt(P/w0) (I + v v^T)^-1/2 diag(v)^-1,
    e = -E w / w0; chi_0 = x_hat + e (weight w0), chi_i = x_hat + E_{*i} (weight w_i).
    With sqrt(P/w0) = S / sqrt(w0): Z_0 = -(I+vv^T)^-1/2 v / sqrt(w0), Z_i = E-pattern columns.
    The paper does not give v; we use v = (1, 1, 1), so w0 = w_i = 1/4.
    """
    va = np.asarray(v, dtype=float)
    if np.any(va == 0.0):
        raise ValueError("AGM needs v_i != 0 (Step 1b)")
    n = va.size
    w0 = 1.0 / (1.0 + float(va @ va))
    wi = w0 * va**2
    M = _sym_sqrt(np.eye(n) + np.outer(va, va))
    Minv = np.linalg.inv(M)
    Epat = Minv @ np.diag(1.0 / va) / np.sqrt(w0)
    e = -Epat @ wi / w0
    return _frozen("agm", np.hstack([e[:, None], Epat]), np.concatenate([[w0], wi]))


PAPER_SETS = ("ahsm", "arm", "agm")


def paper_set(name: str, n: int = 3) -> SigmaSet:
    """The set used in the paper's experiments (n = 3, lam = 12; our w0 = 0.8 and v = 1)."""
    if name == "ahsm":
        return ahsm(n)
    if name == "arm":
        return arm(n)
    if name == "agm":
        return agm(tuple([1.0] * n))
    raise ValueError(f"unknown sigma set {name!r}; choose from {', '.join(PAPER_SETS)}")


def moment_errors(s: SigmaSet) -> tuple[float, float, float]:
    """Max abs errors of sum w - 1, sum w Z (vs 0) and sum w Z Z^T (vs I)."""
    e0 = abs(float(s.w.sum()) - 1.0)
    e1 = float(np.abs(s.Z @ s.w).max())
    e2 = float(np.abs((s.Z * s.w) @ s.Z.T - np.eye(s.n)).max())
    return e0, e1, e2
