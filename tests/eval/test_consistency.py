"""Each estimator's reported covariance against simulated truth (vecu.eval.consistency), on three
held-out seeds of short runs: NEES per dimension, the |z| > 3 tail, NIS per measurement and a
sharpness bound (a sigma no better than the raw sensor's, or than a constant guess, is
"consistent" but worthless). The bounds are tolerant (three short runs), yet a filter whose
process noise Q is 100x too large or 100x too small fails them: checked here too, per estimator."""

from __future__ import annotations

import dataclasses
import math

import pytest

from vecu.estimators.manifold.filters import ManifoldFilterConfig
from vecu.estimators.speed.kf import SpeedFilterConfig
from vecu.estimators.steering.model import SteeringModel
from vecu.eval.consistency import (
    ConsistencyResult,
    Sizes,
    chi2_band,
    run_manifold,
    run_speed,
    run_steering,
    run_throttle,
    summarise,
)
from vecu.models.manifold_params import PAPER_NOISE

SEEDS = (1000, 1001, 1002)
SIZES = Sizes(throttle_steps=20_000, steering_s=30.0, manifold_s=10.0)

# (NEES / d range, |z| > 3 at most, NIS / m range or None, largest mean sigma per state or None)
BOUNDS = {
    "throttle": ((0.3, 4.0), 0.03, None, (10.0,)),  # deg: the accuracy target is 6.5
    "speed": ((0.3, 2.5), 0.02, (0.3, 2.0), (None, 0.6)),  # m/s^2: the raw accelerometer's sigma
    "steering": ((0.25, 2.0), 0.02, (0.2, 3.0), None),
    "manifold": ((0.25, 2.0), 0.02, (0.5, 2.0), None),
}


def violations(r: ConsistencyResult) -> list[str]:
    (lo, hi), z3, nis, sig = BOUNDS[r.estimator]
    out = []
    if not lo <= r.nees / r.dim <= hi:
        out.append(f"NEES/d {r.nees / r.dim:.2f} outside {lo}..{hi}")
    if r.frac_z3 > z3:
        out.append(f"|z|>3 {100 * r.frac_z3:.2f} %")
    if nis is not None:
        assert r.nis is not None
        if not nis[0] <= r.nis / r.nis_dim <= nis[1]:
            out.append(f"NIS/m {r.nis / r.nis_dim:.2f} outside {nis[0]}..{nis[1]}")
    if sig is not None:
        out += [f"sigma {s:.3g} > {m}" for s, m in zip(r.mean_sigma, sig)
                if m is not None and s > m]
    return out


def speed_config(k: float) -> SpeedFilterConfig:
    c = SpeedFilterConfig()
    return dataclasses.replace(c, q_jerk=k * c.q_jerk, q_offset=k * c.q_offset)


def steering_model(k: float) -> SteeringModel:
    m = SteeringModel()
    return dataclasses.replace(m, q_delta=k * m.q_delta, q_vy=k * m.q_vy, q_r=k * m.q_r)


def manifold_config(k: float) -> ManifoldFilterConfig:
    n = PAPER_NOISE
    return ManifoldFilterConfig(noise=dataclasses.replace(
        n, q_et=tuple(k * x for x in n.q_et), q_im=tuple(k * x for x in n.q_im),
        q_tmeas=k * n.q_tmeas))


RUN = {  # estimator -> f(seed, Q scale)
    "throttle": lambda s, k: run_throttle(s, SIZES, False, filter_alpha=math.sqrt(k)),
    "speed": lambda s, k: run_speed(s, SIZES, False, config=speed_config(k)),
    "steering": lambda s, k: run_steering(s, SIZES, False, model=steering_model(k)),
    "manifold": lambda s, k: run_manifold(s, SIZES, False, config=manifold_config(k)),
}


@pytest.mark.parametrize("name", list(RUN))
def test_consistent_and_a_wrong_q_is_caught(name):
    got = {k: summarise(name, [RUN[name](s, k) for s in SEEDS], False) for k in (1.0, 100.0, 0.01)}
    assert violations(got[1.0]) == [], (name, violations(got[1.0]))
    assert violations(got[100.0]), (name, "Q x 100 passed", got[100.0])
    assert violations(got[0.01]), (name, "Q / 100 passed", got[0.01])


def test_chi2_band_of_the_run_mean():
    lo, hi = chi2_band(2, 10)  # chi2(20) / 10: Bar-Shalom's N-run band
    assert lo == pytest.approx(0.959, abs=1e-3) and hi == pytest.approx(3.417, abs=1e-3)
    lo1, hi1 = chi2_band(1, 1)
    assert lo1 == pytest.approx(9.82e-4, rel=1e-2) and hi1 == pytest.approx(5.024, abs=1e-3)
