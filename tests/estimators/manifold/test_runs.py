"""Runs of manifold events in one kernel call (vecu.estimators.manifold.sequences) against
stepping event by event: ManifoldKF.run_events over a drive with bad readings, bad inputs, gated
spikes and a forced divergence gives the same posteriors, final state and counters as step()
(bit for bit), and hands the events it cannot decide alone back to the Python path; the
open-loop observer and the CAC predictions at all events give what the per-event code gives.
Each is compared with the python backend (the reference) under every backend."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu.estimators.manifold import factory as mf
from vecu.estimators.manifold.cac_predict import (
    HORIZON,
    CacPredictionConfig,
    open_loop_temperatures,
    predict_cac,
    prediction_errors,
)
from vecu.eval.manifold import trace_input_array, trace_inputs
from vecu.models.manifold import integrate_manifold, sample_time
from vecu.models.manifold_params import EngineInput
from vecu.plant.drive_profile import DriveProfile, us06_like
from vecu.plant.manifold import simulate

COUNTERS = ("events", "missing", "resets", "bad_inputs", "rejected", "gated", "_gated_run")


@pytest.fixture(scope="module")
def drive(per_backend):
    p = us06_like(9)
    k = round(6.0 / p.dt_s) + 1
    trace = per_backend.reference(
        "trace", lambda: simulate(DriveProfile(p.dt_s, p.n_rpm[:k], p.ta_sp[:k]), seed=9))
    ys = trace.y.copy()
    us = trace_input_array(trace)
    rng = np.random.default_rng(3)
    for n in rng.choice(np.arange(10, len(ys)), size=40, replace=False):
        ys[n, int(rng.integers(3))] = rng.choice([math.nan, 1e6, -5.0])  # rejected channels
    for n in rng.choice(np.arange(10, len(ys)), size=10, replace=False):
        us[n, 1] = rng.choice([math.nan, 0.0, 1e9])  # implausible engine speed
    ys[500:530, 1] += 60.0  # a pressure step: gated, then believed
    return trace, ys, us


def _stepped(name, ys, us, diverge_at):
    flt = mf.make_filter(name)
    xs = np.empty((len(ys), len(flt.x)))
    for n in range(len(ys)):
        if n == diverge_at:
            flt.P[:] = flt.P_post[:] = math.nan
        xs[n] = flt.step(ys[n].tolist(), EngineInput(*us[n].tolist()))
    return xs, flt


def _blocked(name, ys, us, diverge_at):
    flt = mf.make_filter(name)
    a = flt.run_events(ys[:diverge_at], us[:diverge_at])
    flt.P[:] = flt.P_post[:] = math.nan
    b = flt.run_events(ys[diverge_at:], us[diverge_at:])
    return np.vstack([a, b]), flt


@pytest.mark.parametrize("name", ["ekf", "sdkf", "adaptive"])
def test_run_events_is_step_by_step(drive, backend, per_backend, name):
    _, ys, us = drive
    ref_xs, ref = per_backend.reference(("step", name), lambda: _stepped(name, ys, us, 900))
    xs, flt = _blocked(name, ys, us, 900)
    assert np.array_equal(xs, ref_xs), float(np.nanmax(np.abs(xs - ref_xs)))
    assert np.all(np.isfinite(xs))
    for k in COUNTERS:
        assert getattr(flt, k) == getattr(ref, k), k
    for k in ("x", "P", "P_post", "x_post"):
        assert np.array_equal(getattr(flt, k), getattr(ref, k)), k
    assert ref.resets == 1 and sum(ref.gated) >= 10 and min(ref.rejected) > 0
    assert ref.bad_inputs == 10
    assert flt.last_prediction is not None
    assert np.array_equal(flt.last_prediction[1], ref.last_prediction[1])


def test_open_loop_observer_and_predictions_at_all_events(drive, backend, per_backend):
    trace = drive[0]

    def run():
        ol = open_loop_temperatures(trace.y[:, 0], trace.n_rpm, trace.y[0, 1], trace.y[0, 2])
        states = trace.x.copy()
        states[:, 4] = ol
        out = [ol]
        for known in (True, False):
            cfg = CacPredictionConfig(stride=3, known_setpoint=known)
            out.append(prediction_errors(states, trace.ta_sp, trace.n_rpm, trace.cac,
                                         config=cfg)[1])
        return out

    ref, got = per_backend.reference("ol+pred", run), run()
    for a, b in zip(ref, got):
        assert np.array_equal(a, b), float(np.max(np.abs(a - b)))
    # the observer is the event integrator stepped by hand with the measured angle (an oracle)
    p, t, alpha, by_hand = trace.y[0, 1], trace.y[0, 2], math.nan, []
    for n, u in enumerate(trace_inputs(trace)):
        by_hand.append(t)
        ta = float(trace.y[n, 0])
        alpha = ta if math.isfinite(ta) else alpha
        if math.isfinite(alpha):
            p, t, _ = integrate_manifold(p, t, alpha, u, sample_time(u.n_rpm))
    assert np.array_equal(np.array(by_hand), ref[0])
    assert np.ptp(ref[0]) > 1.0 and not np.array_equal(ref[1], ref[2])
    # the predictions are predict_cac's from each state, the setpoints known (an oracle)
    states = trace.x.copy()
    states[:, 4] = ref[0]
    sp, inputs = trace.ta_sp.tolist(), trace_inputs(trace)
    for j, n in enumerate(range(0, len(trace.cac) - HORIZON, 3)):
        if j % 25 == 0:
            hz = [EngineInput(sp[n + k], inputs[n].n_rpm, inputs[n].p_a, inputs[n].t_a,
                              inputs[n].t_cool) for k in range(HORIZON)]
            assert predict_cac(states[n], hz) == ref[1][j], n
