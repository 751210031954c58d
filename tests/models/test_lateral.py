"""vecu.models.lateral's tyre curve, the one copy of D sin(C atan(B alpha)): its value, its slope
against finite differences, the axle forces built on it, and the same bits under every kernel
backend (called directly and from inside the steering model's kernels)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu.estimators.steering import model as sm
from vecu.models import lateral as lat


def _slips(n=400, seed=2):
    rng = np.random.default_rng(seed)
    return [float(a) for a in np.concatenate([rng.normal(0.0, 0.05, n), rng.uniform(-1.0, 1.0, n),
                                              [0.0, -0.0, 1e-12, 0.3, -0.3]])]


def test_tyre_force_is_the_magic_formula_with_its_peak_at_d():
    t = lat.tyre_consts(lat.VehicleParams())
    for a in _slips():
        assert lat.tyre_force.py(t.d_f, t.c, t.b_f, a) == t.d_f * math.sin(
            t.c * math.atan(t.b_f * a))
    # initial slope D C B = C_alpha (the cornering stiffness), peak D where C atan(B a) = pi / 2
    p = lat.VehicleParams()
    slope0 = lat.tyre_force_slope.py(t.d_f, t.c, t.b_f, 0.0)[1]
    assert slope0 == pytest.approx(p.c_f_n_per_rad, rel=1e-12)
    a_peak = math.tan(math.pi / (2.0 * t.c)) / t.b_r
    assert lat.tyre_force.py(t.d_r, t.c, t.b_r, a_peak) == pytest.approx(t.d_r, rel=1e-12)


def test_slope_is_the_derivative_and_its_force_the_force():
    t = lat.tyre_consts(lat.VehicleParams())
    h = 1e-7
    for a in _slips(100):
        f, df = lat.tyre_force_slope.py(t.d_r, t.c, t.b_r, a)
        assert f == lat.tyre_force.py(t.d_r, t.c, t.b_r, a)
        fd = (lat.tyre_force.py(t.d_r, t.c, t.b_r, a + h)
              - lat.tyre_force.py(t.d_r, t.c, t.b_r, a - h)) / (2.0 * h)
        assert abs(df - fd) <= 1e-5 * t.d_r


def test_every_backend_gives_the_reference_bits(backend):
    t = lat.tyre_consts(lat.VehicleParams())
    for a in _slips():
        assert lat.tyre_force(t.d_f, t.c, t.b_f, a) == lat.tyre_force.py(t.d_f, t.c, t.b_f, a)
        assert lat.tyre_force_slope(t.d_r, t.c, t.b_r, a) == \
            lat.tyre_force_slope.py(t.d_r, t.c, t.b_r, a)


def test_plant_and_filter_model_share_the_curve(backend):
    """The plant's f / h and the steering model's accelerations kernel (both lateral_motion:
    compiled under numba for the filter) give the same a_y and r' bit for bit from the filter's
    packed constants (its indices match the vehicle's parameters)."""
    p = lat.VehicleParams()
    t = lat.tyre_consts(p)
    cst = sm.constants(sm.SteeringModel(params=p))
    rng = np.random.default_rng(9)
    for _ in range(200):
        x = tuple(float(v) for v in rng.normal(0.0, [0.5, 0.3, 0.1, 0.5]))
        vx = float(rng.uniform(3.0, 40.0))
        a_y, r_dot = sm.accelerations(x[0], x[1], x[2], vx, cst)
        assert a_y == lat.h((x[0], x[1]), (x[2], vx), p, t)[1]
        assert (a_y - vx * x[1], r_dot) == lat.f((x[0], x[1]), (x[2], vx), p, t)
        assert sm.accelerations(x[0], x[1], x[2], vx, cst) == \
            sm.accelerations.py(x[0], x[1], x[2], vx, cst)
        assert sm.transition(*x, vx, cst) == sm.transition.py(*x, vx, cst)


def test_rk4_step_is_f_and_the_plant_sample_the_same_bits(backend):
    """rk4_motion is the classic RK4 of `f` with the input linear within the step (the sums in
    the reference order), and the plant's one-call sample (sample_motion: h's a_y, then
    SIM_SUBSTEPS RK4 steps) gives the reference bits under every backend."""
    from vecu.plant import lateral as plant

    p = lat.VehicleParams()
    t = lat.tyre_consts(p)
    cst = lat.motion_constants(p, t)
    rng = np.random.default_rng(4)
    for _ in range(200):
        x = (float(rng.normal(0.0, 0.5)), float(rng.normal(0.0, 0.3)))
        u0 = (float(rng.normal(0.0, 0.05)), float(rng.uniform(3.0, 40.0)))
        u1 = (u0[0] + float(rng.normal(0.0, 0.01)), u0[1] + float(rng.normal(0.0, 0.02)))
        dt = 0.005
        um = (0.5 * (u0[0] + u1[0]), 0.5 * (u0[1] + u1[1]))
        k1 = lat.f(x, u0, p, t)
        k2 = lat.f((x[0] + 0.5 * dt * k1[0], x[1] + 0.5 * dt * k1[1]), um, p, t)
        k3 = lat.f((x[0] + 0.5 * dt * k2[0], x[1] + 0.5 * dt * k2[1]), um, p, t)
        k4 = lat.f((x[0] + dt * k3[0], x[1] + dt * k3[1]), u1, p, t)
        ref = tuple(x[i] + dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in (0, 1))
        assert lat.rk4_motion(*x, *u0, *u1, dt, cst) == ref
        assert plant.sample_motion(*x, *u0, *u1, cst) == plant.sample_motion.py(*x, *u0, *u1, cst)
        ay, vy, r = plant.sample_motion.py(*x, *u0, *u1, cst)
        assert ay == lat.h(x, u0, p, t)[1]
        assert (vy, r) == plant.advance_motion.py(*x, *u0, *u1, cst)
