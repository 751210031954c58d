"""The CAC sigmas of ECU_ManifoldSigma (issue 30): first-order propagation through the air
charge of eq. 8 (cac_predict.air_charge_gradient, air_charge_sigmas), checked against finite
differences of models.manifold.cylinder_air_charge and across the kernel backends."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu import kernels
from vecu.estimators.manifold.cac_predict import cac_sigmas
from vecu.estimators.manifold.factory import make_filter
from vecu.models.manifold import cylinder_air_charge, nominal_input
from vecu.models.manifold_params import V8_5L7

X = np.array([0.31, 0.3, 0.29, 61.0, 321.0, 318.0])
P = np.array([[1e-6, 0, 0, 0, 0, 0], [0, 4e-5, 1e-5, 2e-3, 0, 0], [0, 1e-5, 4e-5, 0, 0, 0],
              [0, 2e-3, 0, 0.04, 0.05, 0], [0, 0, 0, 0.05, 4.0, 0.5], [0, 0, 0, 0, 0.5, 1.0]])
U = nominal_input(0.35, 2345.0, V8_5L7)


def test_the_cac_sigma_is_the_finite_difference_gradient_through_the_pt_covariance():
    q = make_filter("sdkf").Q
    now, _ = cac_sigmas(X, P, q, U, V8_5L7)
    p, t, n = X[3], X[4], U.n_rpm
    hp, ht = 1e-4 * p, 1e-4 * t
    g = np.array([(cylinder_air_charge(p + hp, t, n) - cylinder_air_charge(p - hp, t, n)) / (2 * hp),
                  (cylinder_air_charge(p, t + ht, n) - cylinder_air_charge(p, t - ht, n)) / (2 * ht)])
    want = math.sqrt(g @ P[3:5, 3:5] @ g)
    assert now == pytest.approx(want, rel=1e-6)
    assert now > 0.0


def test_the_prediction_sigma_grows_with_the_horizon_and_is_the_estimate_sigma_at_zero():
    q = make_filter("sdkf").Q
    now, zero = cac_sigmas(X, P, q, U, V8_5L7, horizon=0)
    assert zero == now
    sig = [cac_sigmas(X, P, q, U, V8_5L7, horizon=h)[1] for h in (1, 3, 6)]
    assert all(math.isfinite(s) and s > 0.0 for s in sig)
    assert now < sig[0] < sig[1] < sig[2]  # the throttle's uncertainty flows into P_im
    _, scaled = cac_sigmas(X, P, q, U, V8_5L7, eta_scale=1.1)
    assert scaled != sig[-1]


def test_both_backends_give_the_same_sigmas_bit_for_bit():
    if not kernels.numba_available():
        pytest.skip("numba not installed")
    q = make_filter("sdkf").Q
    out = {}
    for backend in ("python", "numba"):
        with kernels.using(backend):
            out[backend] = [cac_sigmas(X, P, q, U, V8_5L7, horizon=h) for h in (0, 6)]
    assert out["python"] == out["numba"]
