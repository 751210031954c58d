"""vecu.kernels.exp.exp_poly: <= 1 ulp over the whole double range (long-double reference),
the same bits under both backends, and the edges (underflow to 0, overflow, NaN)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu import kernels
from vecu.kernels import kernel
from vecu.kernels.exp import exp_poly


@kernel
def _exp_all(x, out):
    for j in range(x.size):
        out[j] = exp_poly(float(x[j]))  # a Python float in plain Python


def _points() -> np.ndarray:
    rng = np.random.default_rng(3)
    k = np.arange(-1076, 1023)
    return np.concatenate([
        np.linspace(-745.2, 709.78, 60_001),
        rng.uniform(-745.2, 709.78, 20_000),
        rng.uniform(-40.0, 0.0, 20_000),  # the particle filter's log-likelihoods
        rng.normal(0.0, 1e-3, 2_000),
        (k + 0.5) * math.log(2.0),  # the reduction's rounding ties
        np.nextafter((k + 0.5) * math.log(2.0), np.inf),
        np.linspace(-745.13, -708.0, 4_001),  # subnormal results
    ])


def _run(x: np.ndarray) -> np.ndarray:
    out = np.empty_like(x)
    _exp_all(x, out)
    return out


@pytest.mark.skipif(np.finfo(np.longdouble).nmant < 60, reason="needs an 80-bit long double")
def test_within_one_ulp_of_the_exact_value(backend):
    x = _points()
    if backend == "python":
        x = x[::8]  # plain Python: a sample (the compiled run takes them all)
    got = _run(x)
    exact = np.exp(x.astype(np.longdouble))
    ulp = np.spacing(exact.astype(np.float64)).astype(np.longdouble)
    err = np.abs(got.astype(np.longdouble) - exact) / ulp
    assert float(err.max()) <= 1.0
    libm = np.array([math.exp(v) for v in x])
    assert np.max(np.abs(got - libm) / np.spacing(libm)) <= 1.0


def test_same_bits_under_both_backends():
    if not kernels.numba_available():
        pytest.skip("numba not installed")
    x = _points()[::4]
    with kernels.using("python"):
        want = _run(x)
    with kernels.using("numba"):
        got = _run(x)
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))


def test_edges(backend):
    x = np.array([0.0, -0.0, 1.0, -745.2, -746.0, -1e300, -math.inf, 709.8, 710.0, math.inf,
                  math.nan, -708.5])
    got = _run(x)
    assert got[0] == 1.0 and got[1] == 1.0 and abs(got[2] - math.e) <= math.ulp(math.e)
    assert got[3] == 0.0 and got[4] == 0.0 and got[5] == 0.0 and got[6] == 0.0
    assert got[7] == math.inf and got[8] == math.inf and got[9] == math.inf
    assert math.isnan(got[10])
    assert 0.0 < got[11] < 2.3e-308 and abs(got[11] - math.exp(-708.5)) <= 5e-324
