"""Fast paths of the manifold model and ECU function against their plain versions: the event
integrator (bit-identical to the ROS2 steps written on vecu.models.manifold._rhs: the bench's
baseline vecu.bench.estimators.integrate_manifold_reference, the oracle here), the SDKF's
3x3 gain, the CAC prediction reusing the filter's own prediction and the float event map."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from vecu.bench.estimators import integrate_manifold_reference
from vecu.models.manifold import integrate_manifold
from vecu.models.manifold_params import V8_5L7, EngineInput


def _cases(rng, n):
    for _ in range(n):
        alpha = rng.choice([rng.uniform(-0.1, 1.7), 0.0, math.pi / 2, rng.uniform(0.1, 0.3)])
        n_rpm = rng.choice([rng.uniform(300.0, 7000.0), 500.0, 6500.0])
        u = EngineInput(rng.uniform(0.0, 1.6), n_rpm, rng.uniform(80.0, 105.0),
                        rng.uniform(250.0, 320.0), rng.uniform(300.0, 380.0))
        # pressures across choked, subsonic, the pr ~ 1 quadratic and reverse flow
        p = rng.choice([rng.uniform(1.0, 120.0), u.p_a * rng.uniform(0.97, 1.03), 0.6])
        t = rng.uniform(250.0, 420.0)
        dt = rng.choice([120.0 / (8.0 * n_rpm), rng.uniform(1e-4, 0.3)])
        yield float(p), t, float(alpha), u, float(dt)


def test_fast_integrator_is_bit_identical_to_theintegrate_manifold_reference():
    rng = np.random.default_rng(7)
    branches = set()
    for p, t, alpha, u, dt in _cases(rng, 600):
        fast = integrate_manifold(p, t, alpha, u, dt)
        ref = integrate_manifold_reference(p, t, alpha, u, dt, V8_5L7)
        assert fast == ref, (p, t, alpha, u, dt)
        pr = p / u.p_a
        branches.add("choked" if pr <= 0.5283 else ("sub" if pr < 0.98 else "quad"))
    assert branches == {"choked", "sub", "quad"}


def test_other_parameter_sets_are_not_served_from_the_cache():
    other = dataclasses.replace(V8_5L7, kappa=1.35, cd_pr=(0.0, 0.4, 0.8, 1.0),
                                cd_table=V8_5L7.cd_table + (V8_5L7.cd_table[-1],),
                                pr_reg=0.97, max_substeps=25)
    u = EngineInput(0.5, 2500.0)
    for p in (20.0, 60.0, 99.0):
        args = (p, 320.0, 0.4, u, 0.006)
        assert integrate_manifold(*args, other) == integrate_manifold_reference(*args, other)
        assert integrate_manifold(*args, other) != integrate_manifold(*args)


def test_filter_gain_shortcut_matches_the_general_update():
    """event.innovation_inverse: the unrolled 3x3 Cholesky (three channels) and LAPACK's (the
    same three as a general set) give S^-1 to 1e-12, along a filtered drive."""
    from vecu.estimators.manifold.event import filter_constants, innovation_inverse
    from vecu.estimators.manifold.factory import make_filter
    from vecu.models.manifold import nominal_input

    rng = np.random.default_rng(5)
    for name in ("sdkf", "ekf"):
        flt = make_filter(name)
        fc = filter_constants(flt.config)
        u = nominal_input(0.3, 2000.0)
        for k in range(200):
            y = (0.3 + rng.normal(0, 0.01), 50.0 + 20 * math.sin(k / 9) + rng.normal(0, 0.1),
                 310.0 + rng.normal(0, 0.05))
            flt.step(y, u)
            P = flt.P
            ok, s_inv = innovation_inverse.py(P, np.array([0, 1, 2]), 3, fc)
            S = P[np.ix_((1, 3, 5), (1, 3, 5))] + flt.R
            ref = np.linalg.inv(S)
            assert ok
            assert np.allclose(s_inv, ref, rtol=1e-11, atol=1e-13 * np.abs(ref).max())
            ok2, two = innovation_inverse.py(P, np.array([0, 2, 0]), 2, fc)
            assert ok2 and np.allclose(two, np.linalg.inv(S[np.ix_((0, 2), (0, 2))]), rtol=1e-11)
        assert flt.resets == 0 and flt.events == 200


def test_manifold_function_prediction_reuses_the_filter_step_exactly():
    """The 6-event CAC prediction starting from the filter's own prediction equals the full one."""
    from vecu.codec import DbcCodec
    from vecu.ecu.manifold_function import ManifoldFunction
    from vecu.estimators.manifold.cac_predict import HORIZON, predict_cac
    from vecu.models.manifold_params import EngineInput
    from vecu.units import RAD_PER_DEG

    fn = ManifoldFunction(DbcCodec())
    rng = np.random.default_rng(2)
    sent = []
    checked = 0
    for k in range(120):
        sp = 10.0 + 60.0 * (k // 30 % 2) + rng.normal(0, 0.2)
        fn._on_event({"ENG_EventCounter": k & 0xFF, "ENG_Speed": 1500.0 + 10 * k,
                      "ENG_ThrottleSetpoint": sp, "ENG_ThrottleAngle": sp + rng.normal(0, 0.5),
                      "ENG_MAP": 40.0 + 0.4 * k}, 0)
        fn._on_iat({"ENG_IntakeCounter": k & 0xFF, "ENG_IAT": 35.0}, 0)
        fn.run(k * 1_000_000, lambda m, values=None: sent.append(m) or True)
        cac6 = fn.last[4]
        x = fn.filter.x_post
        u = EngineInput(sp * RAD_PER_DEG, 1500.0 + 10 * k)  # as the function computes it
        assert fn.filter.last_prediction is not None
        assert cac6 == predict_cac(x, [u] * HORIZON)
        checked += 1
    assert checked == 120 and len(sent) == 240  # ECU_ManifoldSigma + _Estimate per event


def test_predict_state_equals_the_event_map_applied_in_turn():
    from vecu.estimators.manifold.cac_predict import predict_state
    from vecu.models.manifold import f, nominal_input, steady_state_vector

    rng = np.random.default_rng(9)
    x0 = steady_state_vector(nominal_input(0.2, 1200.0))
    for _ in range(40):
        x = x0 + rng.normal(0, [0.01, 0.01, 0.01, 3.0, 2.0, 1.0])
        inputs = [nominal_input(float(rng.uniform(0.13, 1.5)), float(rng.choice([900.0, 3300.0])))
                  for _ in range(6)]
        ref = np.asarray(x, dtype=float)
        for u in inputs:
            ref = f(ref, u)
        assert np.array_equal(predict_state(x, inputs), ref)
