"""One step signature per estimator family: every filter of a family offers its family's Protocol
(vecu/estimators/<family>/base.py) with the same step parameters, and a fixed-lag smoother is a
steering estimator like the filters it wraps (its reset starts afresh)."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from vecu.estimators.manifold.base import ManifoldEstimator
from vecu.estimators.manifold.filters import ManifoldEKF, ManifoldSDKF
from vecu.estimators.registry import make_throttle_estimator
from vecu.estimators.speed.base import SpeedEstimator
from vecu.estimators.speed.kf import SpeedKalmanFilter
from vecu.estimators.steering.base import SteeringEstimator
from vecu.estimators.steering.filters import SteeringEKF, SteeringUKF
from vecu.estimators.steering.smoothers import FixedLagSmoother
from vecu.estimators.throttle.base import ThrottleEstimator
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF
from vecu.plant.lateral import ManoeuvreConfig, simulate_lateral

FAMILIES = [
    (ThrottleEstimator, [lambda: FastThrottleUKF("ahsm"),
                         lambda: make_throttle_estimator("production"),
                         lambda: make_throttle_estimator("open-loop")]),
    (SpeedEstimator, [SpeedKalmanFilter]),
    (SteeringEstimator, [SteeringUKF, SteeringEKF, FixedLagSmoother]),
    (ManifoldEstimator, [ManifoldEKF, ManifoldSDKF]),
]
CASES = [(proto, make) for proto, makes in FAMILIES for make in makes]


def _members(proto) -> set[str]:
    names = set(vars(proto)) | set(getattr(proto, "__annotations__", {}))
    return {n for n in names if not n.startswith("_")}


def _params(fn) -> list[str]:
    return [p for p in inspect.signature(fn).parameters if p != "self"]


@pytest.mark.parametrize("proto, make", CASES, ids=[
    f"{p.__name__}-{i}" for i, (p, _) in enumerate(CASES)])
def test_every_filter_offers_its_familys_protocol(proto, make):
    est = make()
    assert isinstance(est, proto)
    missing = [n for n in _members(proto) if not hasattr(est, n)]
    assert not missing
    # the same step and reset (extra parameters only with defaults)
    step = inspect.signature(type(est).step)
    want = _params(proto.step)
    assert [p for p in step.parameters if p != "self"][:len(want)] == want
    for name in list(step.parameters)[len(want) + 1:]:
        assert step.parameters[name].default is not inspect.Parameter.empty
    reset = inspect.signature(type(est).reset)
    assert all(p.default is not inspect.Parameter.empty
               for n, p in reset.parameters.items() if n != "self")


def test_fixed_lag_smoother_reports_its_filters_estimate_and_restarts_on_reset(backend):
    tr = simulate_lateral(4, ManoeuvreConfig(duration_s=6.0))
    inputs = list(zip(tr.meas_vx.tolist(), tr.meas_r.tolist(), tr.meas_ay.tolist()))
    fl = FixedLagSmoother(0.1)
    for v, r, a in inputs[:300]:
        fl.step(v, r, a)
    f = fl.filter
    assert (fl.swa_rad, fl.swa_std_rad, fl.side_slip_rad, fl.steps, fl.resets, fl.model) == (
        f.swa_rad, f.swa_std_rad, f.side_slip_rad, f.steps, f.resets, f.model)
    fl.reset()
    fresh = FixedLagSmoother(0.1)
    for v, r, a in inputs[300:]:
        got, want = fl.step(v, r, a), fresh.step(v, r, a)
        assert (got is None) == (want is None)
        if got is not None:
            assert (got.step, got.swa_rad, got.side_slip_rad) == (
                want.step, want.swa_rad, want.side_slip_rad)
            np.testing.assert_array_equal(got.x, want.x)
        assert (fl.swa_rad, fl.steps) == (fresh.swa_rad, fresh.steps)
    assert [e.x.tolist() for e in fl.flush()] == [e.x.tolist() for e in fresh.flush()]
