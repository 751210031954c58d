"""The ECU manifold function's event (filter.estimate: the usual event in one filter_events call
over that event with the CAC horizon, vecu.estimators.manifold.sequences) against the separate
calls (filter.step, cylinder_air_charge, predict_cac, what estimate makes for the others):
over a short drive with missing IAT readings, rejected readings, implausible inputs, a gated
pressure step, a forced divergence and a non-positive-definite innovation covariance, the
posteriors, covariances, predictions, CACs and counters are the same bit for bit, under every
backend and against the python backend."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu.estimators.manifold.cac_predict import HORIZON, predict_cac
from vecu.estimators.manifold.factory import make_filter
from vecu.estimators.manifold.filters import ManifoldFilterConfig
from vecu.eval.manifold import trace_inputs
from vecu.models.manifold import cylinder_air_charge
from vecu.models.manifold_params import EngineInput
from vecu.plant.drive_profile import DriveProfile, us06_like
from vecu.plant.manifold import simulate

Y_RANGES = ManifoldFilterConfig().y_ranges
COUNTERS = ("events", "missing", "resets", "bad_inputs", "rejected", "gated", "_gated_run")
BAD_INPUT = 57
DIVERGE, NOT_PD = 300, 420


@pytest.fixture(scope="module")
def drive(per_backend):
    p = us06_like(4)
    a, b = round(2.5 / p.dt_s), round(4.5 / p.dt_s) + 1
    trace = per_backend.reference(
        "trace", lambda: simulate(DriveProfile(p.dt_s, p.n_rpm[a:b], p.ta_sp[a:b]), seed=4))
    rng = np.random.default_rng(5)
    ys = [[float(v) for v in row] for row in trace.y]
    inputs = trace_inputs(trace)
    for n in range(0, len(ys), 7):
        ys[n][2] = math.nan  # the IAT frame missing
    for n in rng.choice(np.arange(20, len(ys)), size=15, replace=False):
        ys[n][int(rng.integers(3))] = float(rng.choice([1e9, -5.0, math.inf]))
    for n in range(200, 225):
        ys[n][1] = 2.0  # a pressure step: gated, then believed
    inputs[BAD_INPUT] = EngineInput(0.3, 1e9)
    return ys, inputs


def _separate(flt, y, u):
    """The separate calls (scale 1)."""
    x = flt.step(y, u)
    cac = cylinder_air_charge(float(x[3]), float(x[4]), u.n_rpm, flt.params)
    first = flt.last_prediction
    if first is not None and first[0] is u:
        return cac, predict_cac(first[1], [u] * (HORIZON - 1), flt.params)
    return cac, predict_cac(x, [u] * HORIZON, flt.params)


def _run(drive, name, fused):
    ys, inputs = drive
    flt = make_filter(name)
    rows, taken = [], 0
    for n, (y, u) in enumerate(zip(ys, inputs)):
        if n == DIVERGE:
            flt.P_post[3, 3] = flt.P[3, 3] = math.nan
        if n == NOT_PD:
            flt.P_post[:] = flt.P[:] = -10.0 * np.eye(6)
        if fused:  # lap() returns 1 s: the prediction's time is 0 when it was one call
            _, cac, cac6, scale, _, predict_s = flt.estimate(y[0], y[1], y[2], u, HORIZON,
                                                             lambda: 1.0)
            done = (cac, cac6)
            taken += predict_s == 0.0
            assert scale == 1.0
        else:
            done = _separate(flt, y, u)
        pred = flt.last_prediction
        rows.append((flt.x_post.copy(), flt.P.copy(), flt.P_post.copy(),
                     None if pred is None else pred[1].copy(), *done))
    return rows, {k: getattr(flt, k) for k in COUNTERS}, taken


@pytest.mark.parametrize("name", ["sdkf", "ekf"])
def test_one_call_gives_the_separate_calls(drive, backend, per_backend, name):
    ref, ref_cnt, _ = per_backend.reference(("sep", name), lambda: _run(drive, name, False))
    for fused in (False, True):
        got, cnt, taken = _run(drive, name, fused)
        assert cnt == ref_cnt
        for n, (a, b) in enumerate(zip(ref, got)):
            for what, va, vb in zip(("x_post", "P", "P_post", "pred", "cac", "cac6"), a, b):
                if va is None or vb is None:
                    assert va is vb, (n, what)
                else:
                    assert np.array_equal(va, vb, equal_nan=True), (n, what, fused)
        if not fused:
            assert taken == 0
        else:  # the usual events in one call, less those the filter kernel hands back
            usual = sum(all(lo <= v <= hi for v, (lo, hi) in zip(y, Y_RANGES))
                        for y in drive[0]) - 1  # the implausible input
            assert usual - 3 <= taken < usual
    assert ref_cnt["resets"] >= 1 and ref_cnt["bad_inputs"] == 1 and sum(ref_cnt["gated"]) >= 5
    assert min(ref_cnt["rejected"]) > 0 and len(ref) > 400
    assert all(math.isfinite(r[4]) and math.isfinite(r[5]) for r in ref)


def test_the_adaptive_filter_makes_the_separate_calls(backend):
    flt = make_filter("adaptive")
    u = EngineInput(0.3, 2000.0)
    for k in range(3):
        *_, predict_s = flt.estimate(0.3, 40.0 + k, 310.0, u, HORIZON, lambda: 1.0)
        assert predict_s == 1.0
    assert flt.events == 3
