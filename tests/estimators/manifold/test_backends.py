"""The manifold SDKF / EKF event and CAC prediction under every kernel backend (numba: the
compiled vecu.estimators.manifold.event kernels) against their Python functions: over a drive
with NaN channels,
missing and out-of-range readings, bad inputs, gated spikes, a forced divergence and a
non-positive-definite innovation covariance, each backend gives the same posteriors,
covariances, predictions and counters bit for bit, twice (numba and numpy call the same
OpenBLAS build here; the assertion messages print the largest relative difference should a BLAS
build ever round differently). The python backend never compiles a kernel."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu import kernels
from vecu.estimators.manifold import filters as mf
from vecu.estimators.manifold.cac_predict import HORIZON, predict_cac, predict_state
from vecu.estimators.manifold.factory import make_filter
from vecu.eval.manifold import trace_inputs
from vecu.models.manifold import nominal_input, steady_state_vector
from vecu.models.manifold_params import EngineInput
from vecu.plant.drive_profile import DriveProfile, us06_like
from vecu.plant.manifold import simulate

COUNTERS = ("events", "missing", "resets", "bad_inputs", "rejected", "gated", "_gated_run")


def _under(name, fn):
    with kernels.using(name):
        return fn()


@pytest.fixture(scope="module")
def drive():
    p = us06_like(6)
    k = round(8.0 / p.dt_s) + 1
    trace = _under("python", lambda: simulate(DriveProfile(p.dt_s, p.n_rpm[:k], p.ta_sp[:k]),
                                              seed=6))
    return trace.y.tolist(), trace_inputs(trace)


def _run_drive(ys, inputs, name="sdkf"):
    """The filter (SDKF or EKF) over the drive with bad data mixed in; per event (x_post, P, P_post, prediction,
    CAC+6 from the filter's prediction, CAC+6 from x_post), plus the counters."""
    rng = np.random.default_rng(12)
    flt = make_filter(name)
    bad_y = [None, (math.nan, 50.0, 300.0), (0.3, math.nan, math.nan), (1e9, -5.0, math.inf),
             ("x", None, 3.0), (0.3, 1e6, 300.0)]
    bad_u = [EngineInput(math.nan, 2000.0), EngineInput(0.3, 1e9), EngineInput(0.3, 2000.0, 5.0)]
    out = []
    for n, (y, u) in enumerate(zip(ys, inputs)):
        y = list(y)
        if n % 3 == 0:
            y[2] = math.nan  # IAT frame missing: two channels
        if rng.random() < 0.08:
            y = bad_y[int(rng.integers(len(bad_y)))]
        if rng.random() < 0.03:
            u = bad_u[int(rng.integers(len(bad_u)))]
        if 400 <= n < 430:
            y = [y[0] if y else 0.3, 99.0, 300.0]  # a pressure step: gated, then believed
        if n == 700:
            flt.P_post[3, 3] = flt.P[3, 3] = math.nan  # forced divergence: the event resets
        if n == 900:
            flt.P_post[:] = flt.P[:] = -10.0 * np.eye(6)  # S not PD: the jitter fallbacks
        x = flt.step(y, u)
        pred = flt.last_prediction
        c6 = predict_cac(pred[1], [pred[0]] * (HORIZON - 1)) if pred else math.nan
        out.append((x, flt.P.copy(), flt.P_post.copy(), pred[1].copy() if pred else None, c6,
                    predict_cac(x, [inputs[n]] * HORIZON)))
    return out, {k: getattr(flt, k) for k in COUNTERS}


def _counted_drive(drive, name="sdkf"):
    """_run_drive plus the number of events that needed the jittered update (_fallback calls)."""
    calls = {"python_event": 0}
    base = mf._ManifoldKF._fallback

    def counting(self, *a):
        calls["python_event"] += 1
        return base(self, *a)

    mf._ManifoldKF._fallback = counting  # type: ignore[method-assign]  # counts, then the same
    try:
        out = _run_drive(*drive, name)
    finally:
        mf._ManifoldKF._fallback = base  # type: ignore[method-assign]  # as above
    return out, calls["python_event"]


def _max_rel(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    both = np.isfinite(a) & np.isfinite(b)
    return float(np.max(np.abs(a - b)[both] / np.maximum(np.abs(a[both]), 1e-300), initial=0.0))


@pytest.mark.parametrize("name", ["sdkf", "ekf"])
def test_filter_event_gives_the_python_reference_over_a_bad_drive(drive, backend, per_backend,
                                                                  name):
    """sdkf_event / ekf_event compiled (numba) against their Python functions."""
    key = f"drive-{name}"
    (py, py_cnt), py_calls = per_backend.reference(key, lambda: _counted_drive(drive, name))
    (got, got_cnt), got_calls = per_backend.get(key, lambda: _counted_drive(drive, name))
    assert len(py) == len(got) > 1500
    names = ("x_post", "P", "P_post", "prediction", "CAC+6 reused", "CAC+6")
    for n, (a, b) in enumerate(zip(py, got)):
        for what, va, vb in zip(names, a, b):
            if va is None or vb is None:
                assert va is vb, (n, what)
                continue
            assert np.array_equal(va, vb, equal_nan=True), (n, what, _max_rel(va, vb))
    assert got_cnt == py_cnt
    # the drive exercised what it should: resets, gating, rejected channels, bad inputs
    assert py_cnt["resets"] == 2 and sum(py_cnt["gated"]) >= 20
    assert min(py_cnt["rejected"]) > 0 and py_cnt["missing"] > 0 and py_cnt["bad_inputs"] > 0
    assert py_calls == got_calls and 1 <= py_calls <= 3  # the fallback (S not PD) ran
    assert len({round(r[5], 9) for r in py}) > 1000  # the predictions move


def test_same_backend_twice_is_bit_identical(drive, backend, per_backend):
    (first, first_cnt), _ = per_backend.get("drive-sdkf", lambda: _counted_drive(drive))
    second, second_cnt = _run_drive(*drive)
    assert first_cnt == second_cnt
    for a, b in zip(first, second):
        for va, vb in zip(a, b):
            assert (va is None and vb is None) or np.array_equal(va, vb, equal_nan=True)


def test_cac_prediction_gives_the_python_reference(backend, per_backend):
    """Held and changing inputs (speed changes per event too), states across the range."""
    rng = np.random.default_rng(21)
    cases = []
    for _ in range(300):
        x = steady_state_vector(nominal_input(float(rng.uniform(0.13, 1.4)), 1500.0))
        x = x + rng.normal(0, [0.01, 0.01, 0.01, 3.0, 2.0, 1.0])
        if rng.random() < 0.5:
            inputs = [nominal_input(float(rng.uniform(0.1, 1.5)),
                                    float(rng.choice([800.0, 2500.0, 5200.0])))
                      for _ in range(int(rng.integers(1, 8)))]
        else:
            inputs = [nominal_input(float(rng.uniform(0.1, 1.5)), float(rng.uniform(700, 6000)))]
            inputs = inputs * int(rng.integers(1, 8))
        cases.append((x, inputs))

    def run():
        return [(predict_state(x, i), predict_cac(x, i)) for x, i in cases]

    py, got = per_backend.reference("cac", run), run()
    for (xa, ca), (xb, cb) in zip(py, got):
        assert np.array_equal(xa, xb) and ca == cb
    assert len({c for _, c in py}) == len(cases)


def test_python_backend_never_compiles(monkeypatch):
    def boom(*a):
        raise AssertionError("kernel compiled under the python backend")

    monkeypatch.setattr(kernels.Kernel, "compiled", property(boom))

    def run():
        flt = make_filter("sdkf")
        u = nominal_input(0.3, 2000.0)
        for k in range(30):
            x = flt.step((0.3, 40.0 + k, 310.0), u)
            predict_cac(x, [u] * HORIZON)
        for k in range(5):
            flt.estimate(0.3, 70.0 + k, 310.0, u, HORIZON, lambda: 0.0)
        return flt

    flt = _under("python", run)
    assert flt.events == 35
