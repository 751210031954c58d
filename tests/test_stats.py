"""vecu.stats.RunningStats: values kept and folded a chunk at a time (welford, compiled under
numba) give the same bits as Welford's update applied to each value as it comes, whenever a
figure is read, under every kernel backend."""

from __future__ import annotations

import math

import numpy as np

from vecu.stats import RunningStats, welford


def _per_value(values):
    """Welford's update applied to each value as it comes (welford on one value at a time)."""
    state = (0, 0.0, 0.0, 0.0, 0.0, 0)
    for x in values:
        state = welford.py([x], *state)
    n, mean, m2, sumsq, max_abs, non_finite = state
    return n, mean, math.sqrt(m2 / n) if n > 1 else 0.0, math.sqrt(sumsq / n), max_abs, non_finite


def test_chunked_fold_gives_the_per_value_bits(backend):
    rng = np.random.default_rng(3)
    values = [float(v) for v in rng.normal(0.5, 3.0, 3 * RunningStats.CHUNK + 17)]
    values[5:5] = [math.nan, math.inf, -math.inf, 7, -2]
    stats = RunningStats()
    for i, x in enumerate(values):
        stats.add(x)
        if i in (0, 3, RunningStats.CHUNK + 1):  # a figure read mid-stream folds early
            assert (stats.n, stats.mean) == _per_value(values[:i + 1])[:2]
    got = (stats.n, stats.mean, stats.std, stats.rms, stats.max_abs, stats.non_finite)
    assert got == _per_value(values)
    assert stats.summary().n == len(values) - 3
    finite = np.array([v for v in values if math.isfinite(v)])  # and Welford is right
    assert math.isclose(stats.mean, float(finite.mean()), rel_tol=1e-12)
    assert math.isclose(stats.std, float(finite.std()), rel_tol=1e-12)
    assert stats.max_abs == float(np.abs(finite).max())


def test_empty_stats_read_zero(backend):
    s = RunningStats()
    assert (s.n, s.mean, s.std, s.rms, s.max_abs, s.non_finite) == (0, 0.0, 0.0, 0.0, 0.0, 0)
