"""The production throttle estimator's particle step and resampling (numba: compiled kernels)
under every kernel backend against the numpy path (the python reference, computed once).

Measured on the run below (alpha = 1, 40 k steps crossing all modes, a 400-step y=None stretch,
an isolated 900 W outlier and five in a row): max |theta difference| 1e-12 deg, every decision
(particle count, Kalman stretch, resampling, rejection) identical at every step. Tolerance
1e-9 deg / identical decisions. Accuracy, calibration, same-seed determinism and reset replay
per backend: tests/estimators/throttle/test_production.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu import kernels
from vecu.estimators.throttle.pf_kernels import (
    CAREFUL,
    PRIOR,
    UPDATE,
    pf_resample,
    pf_step,
)
from vecu.estimators.throttle.pf_parts import systematic_counts
from vecu.estimators.throttle.production import (
    ThrottleParticleFilter,
    make_production_estimator,
)
from vecu.plant.throttle import simulate

THETA_TOL_DEG = 1e-9


@pytest.fixture(scope="module")
def hard_input() -> tuple[list[float], list[float | None]]:
    """alpha = 1 plant input with a blind stretch, an isolated outlier and five in a row (three
    rejected, then believed: the careful update), and a non-finite reading."""
    tr = simulate(40_000, seed=21, noise_scale=1.0)
    y: list[float | None] = tr.y.tolist()
    for k in range(8000, 8400):
        y[k] = None
    y[12_000] = 900.0
    for k in range(20_000, 20_005):
        y[k] = 1500.0
    y[30_000] = math.nan
    return tr.u.tolist(), y


def _trace(est: ThrottleParticleFilter, u, y) -> tuple[np.ndarray, np.ndarray]:
    """Per step: (theta, std) and decisions (n particles, resamples, resizes, kalman steps,
    rejected, resets, careful updates)."""
    out = np.empty((len(y), 2))
    dec = np.empty((len(y), 7), dtype=np.int64)
    up = 0.0
    for k in range(len(y)):
        est.step(up, y[k])
        out[k] = est.theta_deg, est.theta_std_deg
        dec[k] = (est.n_particles, est.resamples, est.resizes, est.kalman_steps, est.rejected,
                  est.resets, est.careful_updates)
        up = u[k]
    return out, dec


def test_hard_run_agrees_with_the_python_reference(hard_input, backend, per_backend):
    u, y = hard_input
    out_py, dec_py = per_backend.reference(
        "hard", lambda: _trace(make_production_estimator(1.0), u, y))
    out_b, dec_b = per_backend.get(
        "hard", lambda: _trace(make_production_estimator(1.0), u, y))
    # the run exercises every path: resizes, resampling, Kalman stretches, the careful update
    assert dec_py[-1, 1] > 1000 and dec_py[-1, 2] > 10 and dec_py[-1, 3] > 5000
    assert dec_py[-1, 6] > 0 and dec_py[-1, 4] >= 5 and dec_py[-1, 5] == 0
    np.testing.assert_array_equal(dec_b, dec_py)  # same decisions at every step
    assert np.max(np.abs(out_b[:, 0] - out_py[:, 0])) <= THETA_TOL_DEG
    assert np.max(np.abs(out_b[:, 1] - out_py[:, 1])) <= THETA_TOL_DEG


def _particles(seed: int, lo: float, hi: float, n: int = 64) -> ThrottleParticleFilter:
    est = ThrottleParticleFilter(1.0, n_high=n, n_low=n, use_kalman=False)
    rng = np.random.default_rng(seed)
    f = est._b.cur
    f.th[:] = rng.uniform(lo, hi, n)
    f.rh[:] = rng.normal(0.0, 40.0, n)
    f.rh[:2] = 0.0
    f.ci[:] = rng.normal(2.0, 2.0, n)
    f.w[:] = rng.uniform(0.1, 1.0, n)
    est._lo, est._hi = float(f.th.min()), float(f.th.max())
    return est


# theta spans: one class (mode 3), straddling the switches (mixed), near 0 (clip at the stop)
@pytest.mark.parametrize("lo, hi", [(20.0, 88.0), (0.5, 40.0), (0.0, 0.4)])
@pytest.mark.parametrize("mode, y", [(PRIOR, None), (UPDATE, 6.0), (CAREFUL, 900.0)])
def test_kernel_step_equals_numpy_step(lo, hi, mode, y, backend):
    """pf_step under the backend (plain Python or compiled) against the numpy methods on the
    same frames: predict (class pick, noise, clip), the update variant, the moments."""
    est = _particles(3, lo, hi)
    b = est._b
    f, g = b.cur, b.nxt
    f0, lo0, hi0 = f.F.copy(), est._lo, est._hi
    with kernels.using("python"):
        sw = est._propagate(b, f, g, 2.5, y, 101, 202, mode == CAREFUL)
    want = g.F[[0, 1, 2, 6]].copy()
    want_out = (sw, est._sw2, est._lo, est._hi, est.theta_deg, est.theta_std_deg)
    g.F[[0, 1, 2, 6]] = np.nan
    f.F[:] = f0
    yc = 0.0 if y is None else y + est._y_shift
    s0, s1, s2, s3, lo_k, hi_k, ci_min = pf_step(
        f.F, g.F, est._mats, est._kconst, est._ztab, b.T, 2.5, lo0, hi0, 101, 202, mode, yc)
    np.testing.assert_allclose(g.F[[0, 1, 2, 6]], want, rtol=1e-12, atol=1e-12)
    assert math.isclose(s0, want_out[0], rel_tol=1e-12)
    assert math.isclose(s3, want_out[1], rel_tol=1e-12)
    assert lo_k == want_out[2] and ci_min == g.ci.min()
    assert hi_k == g.th.max()
    th = s1 / s0
    assert math.isclose(th, float(np.average(g.th, weights=g.w)), rel_tol=1e-12)
    assert math.isclose(s2 / s0 - th * th, float(np.cov(g.th, aweights=g.w, ddof=0)),
                        rel_tol=1e-9)


def test_kernel_resampling_equals_numpy_counts(backend):
    """pf_resample under the backend gives exactly systematic_counts' copies (same draw u0),
    also into a different particle count."""
    est = _particles(5, 10.0, 60.0, n=64)
    b = est._b
    f = b.cur
    f.w[:] = np.random.default_rng(6).exponential(size=64) ** 3
    for n_new in (64, 40, 100):
        counts = systematic_counts(b, f.w, n_new, 0.37)
        want = f.top3.take(b.ar.repeat(counts), axis=1)
        dst = np.full((7, n_new), np.nan)
        assert pf_resample(f.F, dst, n_new, 0.37) == n_new
        np.testing.assert_array_equal(dst[:3], want)
        assert np.all(dst[6] == 1.0)
