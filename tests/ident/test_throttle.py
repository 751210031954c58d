"""Throttle identification (issue 18): a perturbed simulated throttle is recovered, and the ECU's
estimator is more accurate on the identified calibration than on Table I."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vecu.estimators.registry import make_throttle_estimator
from vecu.ident.throttle import identify_throttle
from vecu.ident.trace import ThrottleData, TraceFitError, check_fit_support
from vecu.models.throttle import PAPER_THROTTLE
from vecu.plant.throttle import (
    InputConfig,
    InputGenerator,
    ThrottlePlant,
    ThrottlePlantConfig,
)
from vecu.rng import rng_streams

N = 20_000  # 20 s at 1 kHz (the paper used 3 x 10 000 points)
ALPHA = 0.3  # a quiet throttle body (docs/models.md); at the paper's alpha = 1 see reproduction.md
TRUE = dataclasses.replace(PAPER_THROTTLE, mode3=dataclasses.replace(PAPER_THROTTLE.mode3,
                                                                       b=0.05, a33=0.92))


def _bench(model, steps: int, seed: int = 1) -> tuple[ThrottleData, np.ndarray]:
    """(the data a bench records: u, y, TPS angle with 0.036 deg noise; the true angle)."""
    rngs = rng_streams(seed, ("throttle.input", "throttle.plant"))
    u = np.array(InputGenerator(InputConfig(), rngs["throttle.input"]).take(steps))
    plant = ThrottlePlant(ThrottlePlantConfig(noise_scale=ALPHA, model=model), rngs["throttle.plant"])
    rows = plant.ticks(u)
    th, y = rows[:, 0].copy(), rows[:, 3].copy()
    tps = th + 0.036 * np.random.default_rng(seed).standard_normal(steps)
    return ThrottleData("bench", u, y, tps), th


@pytest.fixture(scope="module")
def fitted():
    data, truth = _bench(TRUE, N)
    return data, truth, identify_throttle(data)


def test_a_perturbed_throttle_is_recovered(fitted) -> None:
    """mode3.b (+13 %) and mode3.a33 (+1.7 %) changed in the plant: both recovered (b within
    10 %, a33 within 0.01), each inside a 95 % interval no wider than 10 % of its value; the
    per-step noise F (0.3 x Table I) within 25 %; the mean squared weighted innovation near 1
    at the fit (the filter's variances right), above it at Table I."""
    _, _, fit = fitted
    est = {e.name: e for e in fit.estimates}
    assert abs(est["mode3.b"].value - 0.05) < 0.005
    assert abs(est["mode3.a33"].value - 0.92) < 0.01
    for name in ("mode3.b", "mode3.a33"):
        assert est[name].status == "fitted" and est[name].ci95 < 0.1 * abs(est[name].value)
    assert est["mode3.a12"].status.startswith("fixed: gauge")
    assert est["mode3.c2"].status.startswith("not identifiable")
    f11, f22, f33 = fit.model.f_diag
    assert f22 == 0.0
    assert abs(f11 / (ALPHA * PAPER_THROTTLE.f_diag[0]) - 1) < 0.25
    assert abs(f33 / (ALPHA * PAPER_THROTTLE.f_diag[2]) - 1) < 0.25
    assert 0.9 < fit.cost_fit < 1.1 < fit.cost_start  # the innovations fit their variances
    assert fit.method.startswith("prediction error through an extended Kalman filter")
    assert set(fit.residuals) == {"mode1", "mode2", "mode3"}


def _rms_error(model, data: ThrottleData, truth: np.ndarray, noise_scale: float = 1.0) -> float:
    est = make_throttle_estimator("production", noise_scale, model)
    err = np.empty(data.n)
    u_prev = 0.0
    for k in range(data.n):
        est.step(u_prev, float(data.y[k]))
        u_prev = float(data.u[k])
        err[k] = est.theta_deg - truth[k]
    return float(np.sqrt(np.mean(err[1000:] ** 2)))


def test_the_identified_calibration_beats_table_i(fitted) -> None:
    """The production estimator on a fresh trace of the same throttle: the identified
    calibration is more accurate than Table I, with the ECU's default alpha and with the true
    alpha given to Table I."""
    _, _, fit = fitted
    data, truth = _bench(TRUE, 8000, seed=2)
    ident = _rms_error(fit.model, data, truth)
    assert ident < 0.8 * _rms_error(PAPER_THROTTLE, data, truth)
    assert ident < 0.8 * _rms_error(PAPER_THROTTLE, data, truth, noise_scale=ALPHA)


def test_a_trace_without_excitation_or_too_short_is_refused() -> None:
    n = 5000
    flat = ThrottleData("flat.blf", np.full(n, 3.0), np.full(n, 2.0), np.linspace(0, 30, n))
    with pytest.raises(TraceFitError, match="flat.blf: no excitation: the motor voltage"):
        check_fit_support(flat)
    still = ThrottleData("still.blf", np.linspace(0, 10, n), np.ones(n), np.full(n, 20.0))
    with pytest.raises(TraceFitError, match="valve angle spans only"):
        check_fit_support(still)
    short = ThrottleData("short.blf", np.linspace(0, 10, 100), np.ones(100), np.ones(100))
    with pytest.raises(TraceFitError, match="too short .* 100 samples"):
        check_fit_support(short)


def test_a_short_trace_says_its_modes_1_2_intervals_are_indicative(fitted) -> None:
    """Below 180 s the report and the JSON carry the note (docs/reproduction.md: 60 s intervals
    of mode 2 too narrow); from 180 s of samples on they do not."""
    from vecu.ident.report import fit_json, format_fit, interval_note

    fit = fitted[2]
    assert fit.n_samples < 180_000
    note = interval_note(fit)
    assert note is not None and "modes 1-2" in note
    assert f"note: {note}" in format_fit(fit) and fit_json(fit)["interval"]["note"] == note
    long = dataclasses.replace(fit, n_samples=180_000)
    assert interval_note(long) is None and "note:" not in format_fit(long)
