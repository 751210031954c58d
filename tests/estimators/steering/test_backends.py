"""The steering UKF + fixed-lag smoother under every kernel backend (the kernels of
vecu.estimators.steering.model / unscented / rts compiled by numba, or run as plain Python) give
exactly (==, measured max |difference| 0) what the Python backend gives, and the same again on a
second run: filter outputs, smoothed outputs, the recorded history and every counter, on a long
manoeuvre and on a run with bad readings, resets, gating and clipping; with the Cholesky
fallback. Each property is one test over the
backends (tests/conftest.py `backend`; the python reference is computed once per module)."""

from __future__ import annotations

import numpy as np
import pytest

from vecu import kernels
from vecu.estimators.common.small_linalg import chol4
from vecu.estimators.steering import rts
from vecu.estimators.steering import unscented as uk
from vecu.estimators.steering.filters import SteeringUKF
from vecu.estimators.steering.history import COL_C, COL_G, COL_PP, N_COLS
from vecu.estimators.steering.smoothers import FixedLagSmoother
from vecu.plant.lateral import ManoeuvreConfig, simulate_lateral

needs_numba = pytest.mark.skipif(not kernels.numba_available(), reason="numba not installed")
BAD = [float("nan"), float("inf"), -float("inf"), 1e9, -1e9, None, 0.0]
COUNTERS = ("steps", "resets", "missing_r", "missing_ay", "missing_vx", "rejected_r",
            "rejected_ay", "rejected_vx", "gated_r", "gated_ay", "clipped")


@pytest.fixture(scope="module")
def long_inputs():
    """100 s of the lateral plant's manoeuvre (10 001 steps of v_x, r, a_y)."""
    tr = simulate_lateral(3, ManoeuvreConfig(duration_s=100.0))
    return list(zip(tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()))


@pytest.fixture(scope="module")
def bad_inputs():
    """20 s with bad readings on every channel and a_y spikes (as tests/estimators/steering/test_filters.py):
    rejections, misses, gating, clipping and one divergence reset."""
    tr = simulate_lateral(7, ManoeuvreConfig(duration_s=20.0))
    vx, r, ay = tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()
    out = []
    for k in range(len(vx)):
        v = BAD[k % 7] if k % 5 == 0 else vx[k]
        y1 = BAD[(k // 3) % 7] if k % 3 == 0 else r[k]
        y2 = BAD[(k // 2) % 7] if k % 2 == 0 else ay[k]
        if k % 97 == 0:
            y2 = 12.0 if (k // 97) % 2 else -12.0
        out.append((v, y1, y2))
    return out


def _run(inputs, lag_s=0.25, maxlen=None):
    """Smoother and a recording UKF over inputs. Returns every output as arrays / tuples."""
    fl = FixedLagSmoother(lag_s)
    ref = SteeringUKF(record=True, history_maxlen=maxlen)
    live, lagged = [], []
    for v, r, a in inputs:
        le = fl.step(v, r, a)
        ref.step(v, r, a)
        f = fl.filter
        live.append((f.swa_rad, f.swa_std_rad, f.side_slip_rad, *f.x.tolist(), *f.P.ravel()))
        if le is not None:
            lagged.append((le.step, le.t_s, *le.x.tolist(), le.swa_rad, le.side_slip_rad))
    tail = [(e.step, *e.x.tolist(), e.swa_rad, e.side_slip_rad) for e in fl.flush()]
    h = ref.history()
    return {"live": np.array(live), "lagged": np.array(lagged), "tail": np.array(tail),
            "hist": np.concatenate([h.x.ravel(), h.P.ravel(), h.x_pred.ravel(), h.P_pred.ravel(),
                                    h.C.ravel(), h.v_x]),
            "counters": [tuple(getattr(f, c) for c in COUNTERS) for f in (fl.filter, ref)]}


def _assert_identical(a, b) -> None:
    assert a["counters"] == b["counters"]
    for key in ("live", "lagged", "tail", "hist"):
        assert a[key].shape == b[key].shape, key
        # measured: max |difference| 0 for every output (bit-identical)
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_long_manoeuvre_gives_the_python_reference_bit_for_bit(backend, per_backend,
                                                               long_inputs) -> None:
    ref = per_backend.reference("long", lambda: _run(long_inputs))
    got = per_backend.get("long", lambda: _run(long_inputs))
    assert ref["lagged"].shape[0] == len(long_inputs) - 25 and ref["tail"].shape[0] == 25
    assert np.all(np.isfinite(ref["lagged"]))
    _assert_identical(ref, got)
    # same backend twice: bit-identical too
    _assert_identical(got, _run(long_inputs))


def test_bad_readings_give_the_python_reference_bit_for_bit(backend, per_backend,
                                                            bad_inputs) -> None:
    ref = per_backend.reference("bad", lambda: _run(bad_inputs, maxlen=300))
    got = per_backend.get("bad", lambda: _run(bad_inputs, maxlen=300))
    c = dict(zip(COUNTERS, ref["counters"][0]))
    assert c["resets"] >= 1 and c["gated_ay"] > 0 and c["clipped"] > 0 and c["rejected_vx"] > 0
    assert ref["hist"].size == 300 * (4 + 16 + 4 + 16 + 16 + 1)  # the bounded ring wrapped
    _assert_identical(ref, got)


@pytest.mark.parametrize("lag_s", [0.0, 0.01, 0.5])
def test_short_and_long_lags(backend, per_backend, long_inputs, lag_s) -> None:
    inputs = long_inputs[:400]
    _assert_identical(per_backend.reference(lag_s, lambda: _run(inputs, lag_s)),
                      _run(inputs, lag_s))


def _non_pd_filter() -> SteeringUKF:
    """A UKF whose P is slightly indefinite (v_y, r correlation 1.0025): the unrolled Cholesky
    fails and covariance.cholesky_lower (eigenvalue clipping) supplies the factor."""
    f = SteeringUKF(record=True)
    f.step(20.0, 0.05, 0.8)
    p = list(f._p)
    p[0] = p[4] = 0.04  # p00 = p11
    p[1] = 0.0401  # p01
    p[2] = p[3] = p[5] = p[6] = 0.0
    f._p = tuple(p)
    return f


def test_cholesky_fallback_gives_the_python_reference(backend, per_backend) -> None:
    p_bad = _non_pd_filter()._p
    assert not chol4.py(p_bad)[0]  # the fallback path is the one taken

    def run():
        f = _non_pd_filter()
        f.step(20.0, 0.05, 0.8)
        # the a_y update from the same non-PD P (the update's own fallback)
        g = SteeringUKF()
        x_ay, p_ay = g._update_ay(f._x, p_bad, 0.7, 20.0)
        return f.x, f.P, f.history().C, x_ay, p_ay, f.resets

    ref = per_backend.reference("fallback", run)
    got = run()
    if backend == "numba":
        assert (uk.predict_with_factor.compiled.signatures
                and uk.ay_moments_with_factor.compiled.signatures)
    assert ref[5] == got[5] == 0 and np.all(np.isfinite(ref[1]))
    assert not np.array_equal(ref[4], p_bad)  # the update was applied
    for a, b in zip(ref, got):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    g = SteeringUKF()
    cst, pts = g._kcst, g._pts
    assert not uk.ay_moments(g._x, p_bad, 20.0, cst, pts)[0]
    assert not uk.predict(g._x, p_bad, 20.0, cst, pts, g._scratch, 0, False)[0]


def test_scalar_update_is_the_kalman_update(backend) -> None:
    """scalar_update (a small kernel: plain Python from the filters; compiled here under numba
    to hold it kernel-compatible) is x + K e, P - K s K^T with K = P h^T / s (numpy matrix form, to 1e-12), the same bits on
    every backend."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        M = rng.normal(size=(4, 4))
        P = M @ M.T + 0.1 * np.eye(4)
        hv = rng.normal(size=4)
        x, e, s = tuple(rng.normal(size=4).tolist()), float(rng.normal()), float(hv @ P @ hv + 0.3)
        c = P @ hv
        p10 = tuple(float(P[i, j]) for i in range(4) for j in range(i, 4))
        run = uk.scalar_update.compiled if backend == "numba" else uk.scalar_update
        xn, pn = run(x, p10, e, s, *c.tolist())
        assert (xn, pn) == uk.scalar_update.py(x, p10, e, s, *c.tolist())
        K = c / s
        np.testing.assert_allclose(xn, np.array(x) + K * e, rtol=1e-12, atol=1e-14)
        Pn = P - np.outer(K, K) * s
        np.testing.assert_allclose(pn, Pn[np.triu_indices(4)], rtol=1e-10, atol=1e-13)


def test_smoother_gain_solves_the_rts_equation(backend) -> None:
    """smoother_gain reads P_pred and C from a ring row and writes G with G P_pred = C
    (row-major, to 1e-12) into the previous row, and nothing else; the same bits on every
    backend (compiled: LAPACK dgesv called directly, plain Python: np.linalg.solve)."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        M = rng.normal(size=(4, 4))
        Pp = M @ M.T + 0.1 * np.eye(4)
        C = rng.normal(size=(4, 4))
        hist = np.zeros((3, N_COLS))
        hist[2, COL_PP:COL_C] = Pp[np.triu_indices(4)]
        hist[2, COL_C:COL_C + 16] = C.ravel()
        ref = hist.copy()
        rts.smoother_gain(hist, 2, 0)
        rts.smoother_gain.py(ref, 2, 0)
        np.testing.assert_array_equal(hist, ref)
        G = hist[0, COL_G:].reshape(4, 4)
        np.testing.assert_allclose(G @ Pp, C, rtol=1e-12, atol=1e-12)
        assert not hist[1].any() and not hist[0, :COL_G].any()
