"""The throttle particle filter's step and resampling: the loops (compiled under numba, as plain
Python otherwise) against their numpy forms (what the python backend runs), and whole runs
under every kernel backend against the python backend's.

Measured on the run below (alpha = 1, 40 k steps crossing all modes, a 400-step y=None stretch,
an isolated 900 W outlier and five in a row): max |theta difference| 1e-12 deg, every decision
(particle count, Kalman stretch, resampling, rejection) identical at every step. Tolerance
1e-9 deg / identical decisions. Accuracy, calibration, same-seed determinism and reset replay
per backend: tests/estimators/throttle/test_filter.py.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np
import pytest

from vecu import kernels
from vecu.estimators.throttle.pf.filter import ThrottleParticleFilter, make_production_estimator
from vecu.estimators.throttle.pf.resample import pf_resample
from vecu.estimators.throttle.pf.state import STATE, StateView, new_state, state_of
from vecu.estimators.throttle.pf.update import CAREFUL, PRIOR, UPDATE, pf_step
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


def test_hard_run_agrees_with_the_python_backend(hard_input, backend, per_backend):
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
    est._s.lo, est._s.hi = float(f.th.min()), float(f.th.max())
    return est


def _loops(k, backend: str):
    """The kernel's loops: compiled (numba) or as plain Python (the oracle of the loops)."""
    return k if backend == "numba" else k.py


# theta spans: one class (mode 3), straddling the switches (mixed), near 0 (clip at the stop)
@pytest.mark.parametrize("lo, hi", [(20.0, 88.0), (0.5, 40.0), (0.0, 0.4)])
@pytest.mark.parametrize("mode, y", [(PRIOR, None), (UPDATE, 6.0), (CAREFUL, 900.0)])
def test_step_loops_equal_the_numpy_step(lo, hi, mode, y, backend):
    """pf_step's loops against its numpy form on the same frames: predict (class pick, noise,
    clip), the update variant, the moments and extremes."""
    est = _particles(3, lo, hi)
    FB, s = est._b.FB, est._s
    cur = int(s.cur)
    f0 = FB.copy()
    yc = 0.0 if y is None else y + s.y_shift
    rec = est._S.view(STATE)[0] if backend == "numba" else s  # the record, as the tick sees it
    args = [FB, cur, est._mats, s, est._ztab, 2.5, s.lo, s.hi, 101, 202, mode, yc, True]
    with kernels.using("python"):
        sw, s_th, s_th2, s_w2, lo_n, hi_n, ci_min_n = pf_step(*args)
    want = FB[1 - cur, [0, 1, 2, 6]].copy()
    FB[:] = f0
    FB[1 - cur, [0, 1, 2, 6]] = np.nan
    args[3] = rec
    s0, s1, s2, s3, lo_k, hi_k, ci_min = _loops(pf_step, backend)(*args)
    g = FB[1 - cur]
    np.testing.assert_allclose(g[[0, 1, 2, 6]], want, rtol=1e-12, atol=1e-12)
    assert math.isclose(s0, sw, rel_tol=1e-12) and math.isclose(s3, s_w2, rel_tol=1e-12)
    assert math.isclose(s1, s_th, rel_tol=1e-12) and math.isclose(s2, s_th2, rel_tol=1e-12)
    assert lo_k == lo_n == g[0].min() and hi_k == hi_n == g[0].max()
    assert ci_min == g[2].min() and ci_min_n == want[2].min()  # (i: equal to rounding)
    th = s1 / s0
    assert math.isclose(th, float(np.average(g[0], weights=g[6])), rel_tol=1e-12)
    assert math.isclose(s2 / s0 - th * th, float(np.cov(g[0], aweights=g[6], ddof=0)),
                        rel_tol=1e-9)


def test_resampling_loops_equal_the_numpy_form(backend):
    """pf_resample's loops give exactly its numpy form's copies (same draw u0), also into a
    different particle count; broken weights: 0, nothing resampled."""
    est = _particles(5, 10.0, 60.0, n=64)
    F = est._b.cur.F
    F[6] = np.random.default_rng(6).exponential(size=64) ** 3
    for n_new in (64, 40, 100):
        want = np.full((7, n_new), np.nan)
        with kernels.using("python"):
            assert pf_resample(F, want, n_new, 0.37) == n_new
        dst = np.full((7, n_new), np.nan)
        assert _loops(pf_resample, backend)(F, dst, n_new, 0.37) == n_new
        np.testing.assert_array_equal(dst[:3], want[:3])
        assert np.all(dst[6] == 1.0) and np.all(want[6] == 1.0)
        # systematic: every particle gets floor or ceil of its expected copies
        counts = np.array([np.sum(np.all(want[:3] == F[:3, [i]], axis=0)) for i in range(64)])
        expected = F[6] / F[6].sum() * n_new
        assert counts.sum() == n_new and np.all(np.abs(counts - expected) < 1.0 + 1e-9)
    F[6, 3] = math.nan
    with kernels.using("python"):
        assert pf_resample(F, np.zeros((7, 64)), 64, 0.37) == 0
    assert _loops(pf_resample, backend)(F, np.zeros((7, 64)), 64, 0.37) == 0


def test_state_view_is_the_record_in_the_same_memory():
    """state_of's two forms: the StateView (Python) and the numpy record (compiled) lay out
    every field of STATE at the same offset, and a write through one reads through the other."""
    for name in STATE.names:
        field = getattr(StateView, name if not STATE.fields[name][0].shape else f"_{name}")
        assert field.offset == STATE.fields[name][1] and field.size == STATE.fields[name][0].itemsize
    assert ctypes.sizeof(StateView) == STATE.itemsize
    S, s = new_state()
    rec = S.view(STATE)[0]
    for name in STATE.names:  # every array field a view of its own place in S
        if STATE.fields[name][0].shape:
            assert np.shares_memory(getattr(s, name), rec[name])
            assert getattr(s, name).__array_interface__["data"] == rec[name].__array_interface__["data"]
    s.lo, s.offs[5], s.kf_x[8] = 1.5, 7.0, -2.0
    assert rec["lo"] == 1.5 and rec["offs"][5] == 7.0 and rec["kf_x"][8] == -2.0
    rec["steps"] = 3.0
    assert s.steps == 3.0
    with kernels.using("python"):
        assert state_of(S) is s
