"""The manifold event integrator as a kernel: under every backend (numba: compiled) it returns
exactly (==) what the Python backend returns, over random states on every flow branch, on a
second parameter set and through the SDKF + 6-event CAC prediction; bad input fails with the
same exception type; the written-out search finds bisect_right's index."""

from __future__ import annotations

import bisect
import dataclasses
import math

import numpy as np
import pytest

from vecu.models import manifold_integrator as mi
from vecu.models.manifold import integrate_manifold, nominal_input
from vecu.models.manifold_params import V8_5L7, EngineInput

OTHER = dataclasses.replace(V8_5L7, kappa=1.35, cd_pr=(0.0, 0.4, 0.8, 1.0),
                            cd_table=V8_5L7.cd_table + (V8_5L7.cd_table[-1],),
                            pr_reg=0.97, max_substeps=25)


def _cases(rng, n):
    """Random events over choked, subsonic, quadratic and reverse flow, both alpha stops, short
    and long intervals (the sub-step clamp at max_substeps included)."""
    for _ in range(n):
        alpha = rng.choice([rng.uniform(-0.1, 1.7), 0.0, math.pi / 2, rng.uniform(0.1, 0.3)])
        n_rpm = float(rng.choice([rng.uniform(300.0, 7000.0), 500.0, 6500.0, 200.0, 8000.0]))
        u = EngineInput(rng.uniform(0.0, 1.6), n_rpm, rng.uniform(80.0, 105.0),
                        rng.uniform(250.0, 320.0), rng.uniform(300.0, 380.0))
        p = rng.choice([rng.uniform(1.0, 120.0), u.p_a * rng.uniform(0.97, 1.03),
                        u.p_a * rng.uniform(1.03, 1.3), 0.6])
        dt = rng.choice([120.0 / (8.0 * n_rpm), rng.uniform(1e-4, 0.3), 0.0])
        yield float(p), rng.uniform(250.0, 420.0), float(alpha), u, float(dt)


def _branch(p, u, prm):
    pr = p / u.p_a
    if pr <= 0.5:
        return "choked"
    if pr < prm.pr_reg:
        return "subsonic"
    return "quadratic" if pr <= 2.0 - prm.pr_reg else "reverse-saturated"


@pytest.mark.parametrize("prm", [V8_5L7, OTHER], ids=["V8_5L7", "other"])
def test_integrator_gives_the_python_reference_bit_for_bit(prm, backend, per_backend):
    cases = list(_cases(np.random.default_rng(11), 1500))
    py = per_backend.reference(prm, lambda: [integrate_manifold(*c, prm) for c in cases])
    got = [integrate_manifold(*c, prm) for c in cases]
    assert len(got) == len(py) == 1500
    for c, a, b in zip(cases, py, got):
        assert a == b, c  # exact: p, t and the sub-step count
        assert type(b[2]) is int and type(b[0]) is float
    assert {_branch(c[0], c[3], prm) for c in cases} == {
        "choked", "subsonic", "quadratic", "reverse-saturated"}
    assert {m for _, _, m in py} >= {1, prm.max_substeps}
    assert len({m for _, _, m in py}) > 10


def test_second_parameter_set_is_not_served_from_the_first_sets_tables(backend,
                                                                        backend_switch):
    args = (60.0, 320.0, 0.4, EngineInput(0.5, 2500.0), 0.006)
    a = integrate_manifold(*args, OTHER)
    b = integrate_manifold(*args)
    assert a != b
    assert a == backend_switch(lambda: integrate_manifold(*args, OTHER), "python")


def test_bad_input_fails_with_the_exception_the_python_code_raised(backend):
    u = EngineInput(0.3, 2000.0)
    cases = [
        ((math.nan, 300.0, 0.3, u, 0.0075), ValueError),  # math.ceil(nan) of the sub-step count
        ((40.0, 300.0, 0.3, u, math.inf), OverflowError),  # math.ceil(inf)
        ((40.0, 300.0, math.nan, u, 0.0075), IndexError),  # C_d lookup at alpha = NaN
        ((40.0, 300.0, 0.3, EngineInput(0.3, math.nan), 0.0075), IndexError),  # eta_N at NaN
        ((40.0, 300.0, 0.3, EngineInput(0.3, 2000.0, 100.0, -5.0), 0.0075), ValueError),  # sqrt
        ((40.0, 300.0, 0.3, EngineInput(0.3, 2000.0, 0.0), 0.0075), ZeroDivisionError),
    ]
    for args, exc in cases:
        with pytest.raises(exc):
            integrate_manifold(*args)


def test_parameter_sets_the_kernels_cannot_take_are_refused(backend):
    """A negative exhaust pressure makes (P_exh/P)^(1/kappa) complex in Python where numba would
    return NaN, a ragged C_d table has no array form: such a set is refused alike under every
    backend, before any event."""
    args = (90.0, 310.0, 0.5, EngineInput(0.5, 3000.0), 0.005)
    ragged = dataclasses.replace(V8_5L7, cd_table=V8_5L7.cd_table[:2] + ((0.6, 0.7),))
    for odd in (dataclasses.replace(V8_5L7, p_exh_kpa=-1.0), ragged,
                dataclasses.replace(V8_5L7, kappa=1.0)):
        with pytest.raises(ValueError, match="manifold parameters"):
            integrate_manifold(*args, odd)
    assert mi.tables(V8_5L7)[1].dtype == np.float64


def test_written_out_search_finds_bisect_rights_index(backend):
    rng = np.random.default_rng(3)
    tables = [(0.0, 0.5, 1.0), (0.0,), (1.0, 1.0, 2.0, 2.0, 3.0), tuple(rng.uniform(0, 1, 9)),
              tuple(np.sort(rng.uniform(0, 1, 12)))]
    probes = [-1.0, 0.0, 0.5, 1.0, 2.0, 3.0, 5.0, math.nan, math.inf, -math.inf,
              *rng.uniform(-0.2, 1.2, 40)]
    for xs in tables:
        arr = np.array(xs)
        for x in probes:
            assert mi.search_right(arr, x) == bisect.bisect_right(xs, x), (xs, x)


def test_sdkf_and_cac_prediction_give_the_python_reference_bit_for_bit(backend, per_backend):
    """The ECU side end to end: 150 SDKF events with the 6-event CAC prediction from each
    posterior; every backend gives the same posteriors, covariances and predictions, bit for
    bit."""
    from vecu.estimators.manifold.cac_predict import HORIZON, predict_cac
    from vecu.estimators.manifold.factory import make_filter

    def run():
        rng = np.random.default_rng(8)
        flt = make_filter("sdkf")
        out = []
        for k in range(150):
            sp = 0.15 + 0.9 * (k // 40 % 2) + rng.normal(0, 0.01)
            u = nominal_input(sp, 1200.0 + 15.0 * k)
            y = (sp + rng.normal(0, 0.01), 35.0 + 0.3 * k + rng.normal(0, 0.1),
                 310.0 + rng.normal(0, 0.05))
            x = flt.step(y, u)
            out.append((x.tolist(), flt.P.tolist(), predict_cac(x, [u] * HORIZON)))
        return out, flt.resets

    (py, py_resets), (got, got_resets) = per_backend.reference("sdkf", run), run()
    assert py_resets == got_resets == 0
    assert got == py
    assert len({round(c, 9) for _, _, c in py}) > 100  # the predictions actually move


def test_int_and_numpy_scalars_reuse_the_one_compiled_signature(backend, backend_switch):
    """An int speed (a DBC signal with scale 1) or numpy scalars convert to float64 instead of
    compiling a second specialisation mid-run; the result equals the float call's."""
    args = (40.0, 310.0, 0.2, EngineInput(0.2, 2000.0), 0.0075)
    ref = integrate_manifold(*args)
    ints = (40, 310, np.float64(0.2), EngineInput(0.2, 2000, 100, 298.15, 363.15), 0.0075)
    assert integrate_manifold(*ints) == ref
    assert backend_switch(lambda: integrate_manifold(*ints), "python") == ref
    if backend == "numba":
        assert len(mi._integrate_event.compiled.signatures) == 1
    assert len(mi._param_consts(V8_5L7)) == mi.N_CONSTS
