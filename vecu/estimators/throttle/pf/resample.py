"""Resampling of the throttle particle filter: when (resample_target) and how (systematic,
pf_resample; its numpy form systematic_numpy is what the python backend runs)."""

from __future__ import annotations

import math

import numpy as np

from vecu.kernels import kernel

ESS_FRACTION = 0.5  # resample when ESS < ESS_FRACTION * N


@kernel
def resample_target(lo: float, n: int, sw: float, sw2: float, n_low: int, n_high: int,
                    low_enter: float, low_exit: float) -> int:
    """The particle count to resample into after a tick, 0 to keep the set: n_low while the
    lowest theta lo is below low_enter, n_high once it is above low_exit (else n); a change of
    count or an ESS sw^2 / sw2 below ESS_FRACTION n resamples."""
    target = n_low if lo < low_enter else (n_high if lo > low_exit else n)
    if target != n or sw * sw < ESS_FRACTION * n * sw2:
        return target
    return 0


def systematic_numpy(src: np.ndarray, dst: np.ndarray, n_new: int, u0: float) -> int:
    """pf_resample's numpy form: the copy counts as floor differences of the scaled cumulative
    weights (no binary search, no Python loop), then one gather."""
    cs = src[6].cumsum()
    if not (cs[-1] > 0.0 and cs[-1] < math.inf):
        return 0
    np.multiply(cs, n_new / float(cs[-1]), out=cs)
    cs += u0
    ics = np.floor(cs).astype(np.intp)
    counts = np.empty_like(ics)
    counts[0] = ics[0]
    np.subtract(ics[1:], ics[:-1], out=counts[1:])
    counts[-1] += n_new - int(ics[-1])  # float rounding of the last cumulative sum
    src[:3].take(np.arange(src.shape[1]).repeat(counts), axis=1, out=dst[:3])
    dst[6].fill(1.0)
    return n_new


@kernel(error_model="numpy", python=systematic_numpy)
def pf_resample(src, dst, n_new, u0):
    """Systematic resampling of src's particles into dst's n_new (rows 0-2, weights 1): copies
    of i = floor(W_i n_new / W + u0) - floor(W_{i-1} n_new / W + u0), W_i cumulative; placed by
    counting floors (no branch on the weights). n_new, or 0 for broken weights."""
    n = src.shape[1]
    total = 0.0
    for i in range(n):
        total += src[6, i]
    if not (total > 0.0 and total < math.inf):
        return 0
    scale = n_new / total
    hits = np.zeros(n_new + 1, dtype=np.int64)
    acc = 0.0
    for i in range(n - 1):
        acc += src[6, i]
        x = acc * scale
        x = x + u0
        ic = math.floor(x)
        hits[min(n_new, ic)] += 1
    run = 0
    for k in range(n_new):
        run += hits[k]
        dst[0, k] = src[0, run]
        dst[1, k] = src[1, run]
        dst[2, k] = src[2, run]
    for j in range(n_new):
        dst[6, j] = 1.0
    return n_new
