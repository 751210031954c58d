# ruff: noqa: FURB136 (explicit selects: their NaN order, the same compiled and in Python)
"""exp(x) as plain arithmetic (range reduction + polynomial): a kernel that LLVM vectorises.

numba compiles `math.exp` to a scalar libm call per element (no SVML here), which dominates
a loop of a few flops per element (the particle filter's likelihoods). `exp_poly` is the
textbook scheme (Cody & Waite reduction, Taylor polynomial; cf. fdlibm's e_exp.c):
  k = round(x / ln 2), r = x - k ln2_hi - k ln2_lo (exact to ~1e-19, |r| <= ln2 / 2),
  exp(r) = sum_{m <= 13} r^m / m! (truncation < 5e-18 relative), exp(x) = 2^k exp(r),
with 2^k built from its bits ((k + 1023) << 52 viewed as a double: integer ops that vectorise,
no table gather) and the scaling split in two where 2^k alone would be subnormal or overflow,
so that the result is rounded once. Error <= 1 ulp
against math.exp over the whole range, subnormal results included (tests/kernels/test_exp.py);
x < -745.2 -> 0, x > 709.8 -> inf, NaN -> NaN. Rounding differs from libm's / numpy's by at
most an ulp: use it where agreement to rounding is the contract.
"""

from __future__ import annotations

import numpy as np

from vecu.kernels import kernel

_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01  # fdlibm's split: k * _LN2_HI is exact for |k| < 2^11
_LN2_LO = 1.90821492927058770002e-10
_ROUND = 6755399441055744.0  # 1.5 * 2^52: (v + _ROUND) - _ROUND rounds v to an integer
_X_MIN = -746.0  # exp(-745.14) is half the smallest subnormal: below, the result is 0
_X_MAX = 710.0  # exp(709.79) overflows
_K_MIN = -1022  # the smallest normal exponent
_SPLIT = 60  # extra scaling 2^(-+60) where 2^k alone would leave the normal range
_TINY = 2.0 ** -_SPLIT
_HUGE = 2.0 ** _SPLIT


@kernel
def exp_poly(x: float) -> float:
    """e^x to <= 1 ulp without a libm call (see the module docstring)."""
    x = _X_MIN if x < _X_MIN else (_X_MAX if x > _X_MAX else x)  # NaN passes through
    kf = x * _LOG2E + _ROUND
    kf = kf - _ROUND
    r = x - kf * _LN2_HI
    r = r - kf * _LN2_LO
    p = 1.0 / 6227020800.0  # 1/13!
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = (r * r) * p + r  # e^r - 1: the large terms added last, so 1 + p rounds once
    p = p + 1.0
    k = int(kf) if kf == kf else 0  # |k| <= 1077 after the clamp
    tiny = k < _K_MIN + 1
    huge = k > 1000
    k = k + _SPLIT if tiny else (k - _SPLIT if huge else k)
    scale = _TINY if tiny else (_HUGE if huge else 1.0)
    two_k = float(np.int64((k + 1023) << 52).view(np.float64))  # 2^k: its bits
    return (p * two_k) * scale
