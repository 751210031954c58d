"""Small unrolled Cholesky factorisations (3x3, 4x4) and the 3x3 SPD inverse, the one copy for
every filter that factors a small covariance in plain floats. Symmetric inputs as the upper
triangle row by row, lower factors row by row; Cholesky-Banachiewicz in the operation order the
golden logs depend on. A pivot not > 0 (NaN included) gives ok = False and zeros; the callers'
fallback: `chol3_or_fallback` / `chol4_or_fallback` (covariance.cholesky_lower), `chol3_floored`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.estimators.common.covariance import cholesky_lower
from vecu.kernels import kernel

L3 = tuple[float, float, float, float, float, float]
L4 = tuple[float, float, float, float, float, float, float, float, float, float]


@kernel(small=True)
def chol3(p: Any) -> tuple[bool, L3]:
    """(ok, lower factor) of the 3x3 SPD matrix p (upper triangle, module docstring)."""
    p00, p01, p02, p11, p12, p22 = p
    if p00 > 0.0:
        l00 = math.sqrt(p00)
        l10 = p01 / l00
        l20 = p02 / l00
        d = p11 - l10 * l10
        if d > 0.0:
            l11 = math.sqrt(d)
            l21 = (p12 - l20 * l10) / l11
            d = p22 - l20 * l20 - l21 * l21
            if d > 0.0:
                return True, (l00, l10, l11, l20, l21, math.sqrt(d))
    return False, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@kernel(small=True)
def chol4(p: Any) -> tuple[bool, L4]:
    """(ok, lower factor) of the 4x4 SPD matrix p (upper triangle, module docstring)."""
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
    if p00 > 0.0:
        l00 = math.sqrt(p00)
        l10, l20, l30 = p01 / l00, p02 / l00, p03 / l00
        d = p11 - l10 * l10
        if d > 0.0:
            l11 = math.sqrt(d)
            l21 = (p12 - l20 * l10) / l11
            l31 = (p13 - l30 * l10) / l11
            d = p22 - l20 * l20 - l21 * l21
            if d > 0.0:
                l22 = math.sqrt(d)
                l32 = (p23 - l30 * l20 - l31 * l21) / l22
                d = p33 - l30 * l30 - l31 * l31 - l32 * l32
                if d > 0.0:
                    return True, (l00, l10, l11, l20, l21, l22, l30, l31, l32, math.sqrt(d))
    return False, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@kernel(small=True)
def chol3_floored(p: Any, floor: float) -> L3:
    """Lower factor of the 3x3 matrix p with every pivot floored at `floor` (never fails; a tiny
    jitter where P is not positive definite). floor if floor > d else d is max(d, floor) as
    Python computes it, NaN included."""
    p00, p01, p02, p11, p12, p22 = p
    l00 = math.sqrt(floor if floor > p00 else p00)  # noqa: FURB136 (max(), NaN included; docstring)
    l10 = p01 / l00
    l20 = p02 / l00
    d = p11 - l10 * l10
    l11 = math.sqrt(floor if floor > d else d)  # noqa: FURB136 (as above)
    l21 = (p12 - l20 * l10) / l11
    d = p22 - l20 * l20 - l21 * l21
    return l00, l10, l11, l20, l21, math.sqrt(floor if floor > d else d)  # noqa: FURB136 (as above)


@kernel(small=True)
def inverse_from_chol3(low: Any) -> L3:
    """S^-1 (upper triangle) from chol3's factor L of S: S^-1 = M^T M with M = L^-1 (lower)."""
    l00, l10, l11, l20, l21, l22 = low
    m00, m11, m22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    m10 = -l10 * m00 * m11
    m21 = -l21 * m11 * m22
    m20 = -(l20 * m00 + l21 * m10) * m22
    return (m00 * m00 + m10 * m10 + m20 * m20, m10 * m11 + m20 * m21, m20 * m22,
            m11 * m11 + m21 * m21, m21 * m22, m22 * m22)


def chol3_or_fallback(p: Any) -> L3:
    """chol3's factor, or covariance.cholesky_lower's (jitter, then eigenvalue clipping) when P
    is not positive definite for it (plain Python)."""
    ok, low = chol3(p)
    if ok:
        return low
    p00, p01, p02, p11, p12, p22 = p
    L = cholesky_lower(np.array([[p00, p01, p02], [p01, p11, p12], [p02, p12, p22]]))
    return (float(L[0, 0]), float(L[1, 0]), float(L[1, 1]),
            float(L[2, 0]), float(L[2, 1]), float(L[2, 2]))


def chol4_or_fallback(p: Any) -> L4:
    """chol4's factor, or covariance.cholesky_lower's (jitter, then eigenvalue clipping) when P
    is not positive definite for it (plain Python)."""
    ok, low = chol4(p)
    if ok:
        return low
    p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = p
    L = cholesky_lower(np.array([[p00, p01, p02, p03], [p01, p11, p12, p13],
                                 [p02, p12, p22, p23], [p03, p13, p23, p33]]))
    return (float(L[0, 0]), float(L[1, 0]), float(L[1, 1]), float(L[2, 0]), float(L[2, 1]),
            float(L[2, 2]), float(L[3, 0]), float(L[3, 1]), float(L[3, 2]), float(L[3, 3]))
