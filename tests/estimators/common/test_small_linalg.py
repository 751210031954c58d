"""vecu.estimators.common.small_linalg: the unrolled 3x3 / 4x4 Cholesky factors and the 3x3 SPD
inverse equal numpy's to rounding, fail (ok False) exactly where a pivot is not > 0, keep their
fallbacks, and give bit-identical results under every kernel backend (called directly and from
inside another kernel)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu.estimators.common import small_linalg as sl
from vecu.kernels import kernel


@kernel
def _factor_and_invert(p3):
    """A kernel calling the shared ones (as the steering and manifold kernels do)."""
    ok, low = sl.chol3(p3)
    if not ok:
        return False, low
    return True, sl.inverse_from_chol3(low)


def _spd(rng, n, scale=1.0):
    M = rng.normal(size=(n, n)) * scale
    return M @ M.T + 1e-3 * scale * scale * np.eye(n)


def _upper(P):
    return tuple(float(v) for v in P[np.triu_indices(P.shape[0])])


def _lower(L):
    return tuple(float(v) for v in L[np.tril_indices(L.shape[0])])


def _matrices(seed=3, count=300):
    """SPD matrices over 12 decades, indefinite ones, and ones with NaN / inf entries."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        P = _spd(rng, 4, float(10.0 ** rng.integers(-6, 6)))
        if k % 5 == 0:
            P[1, 1] = P[0, 1] * P[0, 1] / P[0, 0] * 0.999  # second pivot < 0
        if k % 11 == 0:
            P[2, 3] = P[3, 2] = float(rng.choice([math.nan, math.inf]))
        out.append(P)
    return out


def test_factors_match_numpy_and_fail_where_a_pivot_is_not_positive(backend):
    fails = 0
    for P in _matrices():
        for n, chol in ((3, sl.chol3), (4, sl.chol4)):
            A = P[:n, :n]
            ok, low = chol(_upper(A))
            if not np.all(np.isfinite(A)):
                assert not ok  # a NaN or inf reaches a pivot
            else:
                try:
                    L = np.linalg.cholesky(A)
                except np.linalg.LinAlgError:
                    L = None
                assert ok is (L is not None)
                if ok:
                    np.testing.assert_allclose(low, _lower(L), rtol=1e-9,
                                               atol=1e-12 * float(abs(L).max()))
            if not ok:
                fails += 1
                assert low == (0.0,) * len(low)
    assert 100 < fails < 400


def test_inverse_from_the_factor_is_s_inverse(backend):
    rng = np.random.default_rng(4)
    for _ in range(200):
        S = _spd(rng, 3, float(10.0 ** rng.integers(-3, 4)))
        ok, inv = _factor_and_invert(_upper(S))
        assert ok
        np.testing.assert_allclose(inv, _upper(np.linalg.inv(S)), rtol=1e-8)
    assert not _factor_and_invert((1.0, 1.0, 0.0, 1.0, 0.0, 1.0))[0]


def test_floored_factor_never_fails_and_equals_chol3_on_spd():
    rng = np.random.default_rng(5)
    for _ in range(200):
        p = _upper(_spd(rng, 3))
        assert sl.chol3_floored.py(p, 1e-12) == sl.chol3.py(p)[1]
    low = sl.chol3_floored.py((0.0, 0.0, 0.0, -1.0, 0.0, 1.0), 1e-12)
    assert low[0] == low[2] == math.sqrt(1e-12) and low[5] == 1.0
    nan = sl.chol3_floored.py((math.nan, 0.0, 0.0, 1.0, 0.0, 1.0), 1e-12)
    assert math.isnan(nan[0])  # max(NaN, floor) is NaN in Python: kept


def test_fallbacks_factor_what_the_unrolled_code_refuses():
    P = np.array([[0.04, 0.0401, 0.0, 0.0], [0.0401, 0.04, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0]])  # correlation 1.0025: slightly indefinite
    assert not sl.chol4.py(_upper(P))[0] and not sl.chol3.py(_upper(P[:3, :3]))[0]
    for n, fb in ((3, sl.chol3_or_fallback), (4, sl.chol4_or_fallback)):
        low = fb(_upper(P[:n, :n]))
        assert all(math.isfinite(v) for v in low)
        L = np.zeros((n, n))
        L[np.tril_indices(n)] = low
        assert np.abs(L @ L.T - P[:n, :n]).max() < 1e-3  # eigenvalues clipped
        p = _upper(_spd(np.random.default_rng(n), n))
        assert fb(p) == (sl.chol3 if n == 3 else sl.chol4).py(p)[1]


@pytest.mark.parametrize("name", ["chol3", "chol4", "inverse_from_chol3"])
def test_every_backend_gives_the_python_reference_bit_for_bit(backend, name):
    k = getattr(sl, name)
    cases = [_upper(P[:3, :3]) if name != "chol4" else _upper(P) for P in _matrices(7)]
    if name == "inverse_from_chol3":
        cases = [sl.chol3.py(c)[1] for c in cases if sl.chol3.py(c)[0]]
    assert len(cases) > 100
    for c in cases:
        got, ref = k(c), k.py(c)
        assert repr(got) == repr(ref)  # bit-identical, NaN included
    p = (4.0, 1.0, 0.5, 3.0, 0.25, 2.0)
    assert repr(_factor_and_invert(p)) == repr(_factor_and_invert.py(p))
