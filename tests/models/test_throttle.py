"""vecu.models.throttle's eq. (3), the one copy (mode_step / eq3_step): Table I's equation term
by term, the switching, the same bits under every kernel backend and inside the kernels that call
it (plant ticks, identification, the paper UKF's prediction), and the particle filter's class
matrices read off it for any calibration."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vecu.estimators.throttle.pf.model import class_b, class_matrix_stack
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF
from vecu.ident.kernels import free_run
from vecu.models import throttle as mt
from vecu.models.throttle import PAPER_THROTTLE, TABLE_I, ModeParams, ThrottleModel
from vecu.plant.throttle import plant_step


def _sgn(v: float) -> float:
    return math.copysign(1.0, v) if v != 0.0 and not math.isnan(v) else 0.0


def _states(n=300, seed=4):
    """theta over all modes and the switching angles, rho and i with zeros, and NaN."""
    rng = np.random.default_rng(seed)
    th = np.concatenate([rng.uniform(-5.0, 95.0, n), [0.0, 1.0, 8.0, 16.0, 8.0 + 1e-12, 90.0]])
    rh = np.concatenate([rng.normal(0.0, 20.0, n), [0.0, -0.0, 1.0, -1.0, 0.0, 3.0]])
    ci = np.concatenate([rng.normal(2.0, 5.0, n), [0.0, 1.0, -2.0, 3.0, 0.0, 40.0]])
    u = np.concatenate([rng.uniform(0.0, 10.0, n), [0.0, 5.0, 10.0, 1.0, 2.0, 3.0]])
    return [tuple(float(v) for v in s) for s in zip(th, rh, ci, u)]


def _random_model(seed: int) -> ThrottleModel:
    """Table I with every coefficient off by ~10 %, other switching angles."""
    rng = np.random.default_rng(seed)
    modes = [ModeParams(*(float(v) for v in np.array(p.row) * rng.normal(1.0, 0.1, 10)))
             for p in TABLE_I]
    return dataclasses.replace(PAPER_THROTTLE, mode1=modes[0], mode2=modes[1], mode3=modes[2],
                               mode_bounds_deg=(6.5, 21.25))


def test_eq3_is_table_i_term_by_term():
    """theta' = theta + a12 rho, rho' = a21 theta + a22 rho + a23 i + c1 sgn rho
    + c2 sgn(theta - 1) + c3, i' = a32 rho + a33 i + b u, mode by theta (8, 16 deg)."""
    for th, rh, ci, u in _states():
        p = TABLE_I[0 if th <= 8.0 else (1 if th <= 16.0 else 2)]
        want = (th + p.a12 * rh,
                p.a21 * th + p.a22 * rh + p.a23 * ci + p.c1 * _sgn(rh) + p.c2 * _sgn(th - 1.0)
                + p.c3,
                p.a32 * rh + p.a33 * ci + p.b * u)
        assert mt.eq3_step.py(PAPER_THROTTLE.rows, 8.0, 16.0, th, rh, ci, u) == want
        assert mt.step_mean(th, rh, ci, u) == want
    th = math.nan  # NaN selects mode 3 (as the former copies did)
    assert math.isnan(mt.eq3_step.py(PAPER_THROTTLE.rows, 8.0, 16.0, th, 1.0, 1.0, 1.0)[0])
    assert mt.eq3_step.py(PAPER_THROTTLE.rows, 8.0, 16.0, th, 1.0, 1.0, 1.0)[2] == \
        TABLE_I[2].a32 + TABLE_I[2].a33 + TABLE_I[2].b


def test_mode_step_works_elementwise_on_arrays():
    s = np.array(_states(100))
    th, rh, ci, u = s.T
    p = PAPER_THROTTLE.rows[1]
    got = mt.mode_step.py(p, th, rh, ci, u, np.sign(rh), np.sign(th - 1.0))
    for j in range(len(th)):
        want = mt.mode_step.py(p, float(th[j]), float(rh[j]), float(ci[j]), float(u[j]),
                               _sgn(float(rh[j])), _sgn(float(th[j]) - 1.0))
        assert (got[0][j], got[1][j], got[2][j]) == want


def test_every_backend_gives_the_reference_bits(backend):
    """Called directly and from inside the plant, identification and UKF kernels."""
    model = _random_model(1)
    rows, arr = model.rows, np.array(model.rows)
    b1, b2 = model.mode_bounds_deg
    for th, rh, ci, u in _states():
        ref = mt.eq3_step.py(rows, b1, b2, th, rh, ci, u)
        assert mt.eq3_step(rows, b1, b2, th, rh, ci, u) == ref
        assert mt.eq3_step(arr, b1, b2, th, rh, ci, u) == ref
        assert plant_step(arr, b1, b2, 0.5, 0.4, th, rh, ci, u, 0.3, -0.2) == \
            plant_step.py(rows, b1, b2, 0.5, 0.4, th, rh, ci, u, 0.3, -0.2)
    us = np.array([s[3] for s in _states()])
    out = [np.empty(us.size) for _ in range(4)]
    free_run(arr, b1, b2, us, 12.0, 1.0, out[0], out[1])
    free_run.py(arr, b1, b2, us, 12.0, 1.0, out[2], out[3])
    assert np.array_equal(out[0], out[2]) and np.array_equal(out[1], out[3])
    t, r, c = 12.0, 0.0, 1.0
    for k in range(us.size):  # free_run is eq3_step + the clip, step after step
        assert (out[0][k], out[1][k]) == (t, c)
        tn, r, c = mt.eq3_step.py(rows, b1, b2, t, r, c, float(us[k]))
        t = mt.clip_theta.py(tn)


def test_paper_ukf_prediction_is_the_same_on_every_backend(backend):
    """FastThrottleUKF's compiled sigma-point prediction gives the Python function's bits."""
    from vecu import kernels

    def run() -> list[tuple[float, ...]]:
        f = FastThrottleUKF("ahsm", model=_random_model(2))
        rng = np.random.default_rng(3)
        out = []
        for k in range(300):
            f.step(float(rng.uniform(0.0, 10.0)), float(rng.uniform(0.0, 30.0)) if k % 5 else None)
            out.append(f.x + f.p)
        return out

    got = run()
    with kernels.using("python"):
        assert got == run()


@pytest.mark.parametrize("seed", [0, 5, 6])
def test_class_matrices_are_the_models_coefficients(seed):
    """The particle filter's class matrices, read off mode_step, hold each calibration's
    coefficients exactly: [theta, rho, i, 1, sgn rho] -> (theta', rho', i' - b u) per class."""
    model = PAPER_THROTTLE if seed == 0 else _random_model(seed)
    m = class_matrix_stack(model)
    for c, (mode, s_th) in enumerate([(0, -1.0), (0, 1.0), (1, 1.0), (2, 1.0)]):
        p = model.modes[mode]
        want = [[1.0, p.a12, 0.0, 0.0, 0.0],
                [p.a21, p.a22, p.a23, p.c2 * s_th + p.c3, p.c1],
                [0.0, p.a32, p.a33, 0.0, 0.0]]
        assert m[3 * c:3 * c + 3].tolist() == want
        assert class_b(model)[c] == p.b
