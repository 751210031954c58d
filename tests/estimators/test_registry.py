"""The ECU's throttle calibration reaches every throttle estimator (issue 18): each one takes a
ThrottleModel (eq. 3 modes, switching angles, F, H), Table I by default."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vecu import kernels
from vecu.estimators.registry import THROTTLE_ESTIMATORS, make_throttle_estimator
from vecu.models.throttle import PAPER_THROTTLE, ThrottleModel
from vecu.plant.throttle import simulate

STEPS = 400


def _thetas(est, tr) -> np.ndarray:
    out = np.empty(STEPS)
    u_prev = 0.0
    for k in range(STEPS):
        est.step(u_prev, float(tr.y[k]))
        u_prev = float(tr.u[k])
        out[k] = est.theta_deg
    return out


def _other_throttle() -> ThrottleModel:
    m = PAPER_THROTTLE
    return dataclasses.replace(
        m, mode1=dataclasses.replace(m.mode1, b=0.09), mode3=dataclasses.replace(m.mode3, b=0.06),
        mode_bounds_deg=(7.5, 17.25), f_diag=(0.5, 0.0, 0.35), h_wattmeter=1.3)


@pytest.mark.parametrize("name", THROTTLE_ESTIMATORS)
def test_each_estimator_runs_on_the_calibration_it_is_given(name: str) -> None:
    tr = simulate(STEPS, seed=3, noise_scale=0.3)
    base = _thetas(make_throttle_estimator(name, 0.3), tr)
    same = _thetas(make_throttle_estimator(name, 0.3, PAPER_THROTTLE), tr)
    other = _thetas(make_throttle_estimator(name, 0.3, _other_throttle()), tr)
    assert np.array_equal(base, same)  # Table I given explicitly = the default
    assert not np.allclose(base, other)  # another throttle body: another estimate
    assert np.all(np.isfinite(other))


def test_production_with_fractional_switching_angles_agrees_across_backends() -> None:
    """Bounds that are not whole degrees take the searchsorted class lookup under numpy and the
    compiled comparisons under numba: the same classes, so the same estimates (to rounding)."""
    if not kernels.numba_available():
        pytest.skip("numba not installed")
    tr = simulate(STEPS, seed=5, noise_scale=1.0)
    model = _other_throttle()
    with kernels.using("python"):
        py = _thetas(make_throttle_estimator("production", 1.0, model), tr)
    with kernels.using("numba"):
        nb = _thetas(make_throttle_estimator("production", 1.0, model), tr)
    np.testing.assert_allclose(py, nb, atol=1e-6)


def test_every_family_has_one_name_to_estimator_registry():
    """ESTIMATORS: each family's names each make a fresh estimator, an unknown name is a user
    error."""
    from vecu.errors import BadArgumentError
    from vecu.estimators.registry import ESTIMATORS

    assert set(ESTIMATORS) == {"throttle", "speed", "steering", "manifold"}
    for family in ESTIMATORS.values():
        for name in family.names:
            first, second = family.make(name), family.make(name)
            assert first is not second and type(first) is type(second)
    for family in ("throttle", "speed", "steering"):
        with pytest.raises(BadArgumentError):
            ESTIMATORS[family].make("no-such-filter")
    with pytest.raises(ValueError):
        ESTIMATORS["manifold"].make("no-such-filter")
