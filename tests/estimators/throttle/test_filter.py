"""Production throttle estimator (vecu.estimators.throttle.pf) against simulated truth.

Accuracy is checked on 60 k steps per alpha (the 200 k-step, 3-seed figures are in
docs/models.md); the tolerances leave room for the Monte-Carlo spread of a 60 k-step run, they are
not the spec (6.5 deg at alpha = 1, 2.2 deg at alpha = 0.3 over 200 k steps). Accuracy,
calibration, determinism and the outlier redo are checked under every kernel backend
(tests/conftest.py `backend`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vecu.estimators.registry import make_throttle_estimator
from vecu.estimators.throttle.pf.filter import ThrottleParticleFilter, make_production_estimator
from vecu.estimators.throttle.pf.kalman_stretch import mode3_predict, mode3_update, set_constants
from vecu.estimators.throttle.pf.model import class_matrix_stack
from vecu.estimators.throttle.pf.state import new_state
from vecu.models.throttle import TABLE_I, step_mean
from vecu.plant.throttle import simulate

BURN_IN = 1000


def _run(est, trace) -> tuple[np.ndarray, np.ndarray]:
    u, y = trace.u.tolist(), trace.y.tolist()
    th = np.empty(len(y))
    sd = np.empty(len(y))
    up = 0.0
    for k in range(len(y)):
        est.step(up, y[k])
        th[k] = est.theta_deg
        sd[k] = est.theta_std_deg
        up = u[k]
    return th, sd


@pytest.fixture(scope="module")
def traces() -> dict[float, object]:
    return {a: simulate(60_000, seed=11, noise_scale=a) for a in (1.0, 0.3)}


@pytest.fixture
def runs(traces, backend, per_backend
         ) -> dict[float, tuple[np.ndarray, np.ndarray, ThrottleParticleFilter]]:
    """Both traces through the estimator under each kernel backend (once per backend)."""

    def run():
        out = {}
        for a, tr in traces.items():
            est = make_production_estimator(a)
            th, sd = _run(est, tr)
            out[a] = (th, sd, est)
        return out

    return per_backend.get("runs", run)


# Measured on this trace (seed 11, 60 k steps): error std 6.17 deg (alpha 1; 6.05 with 1000
# particles near the switches before issue 32), 1.83 deg (0.3).
@pytest.mark.parametrize("alpha, max_std, max_abs_mean", [(1.0, 7.0, 1.5), (0.3, 2.4, 0.5)])
def test_accuracy_against_true_theta(traces, runs, alpha, max_std, max_abs_mean):
    th, _, est = runs[alpha]
    e = th[BURN_IN:] - traces[alpha].theta[BURN_IN:]
    assert e.std() <= max_std
    assert abs(e.mean()) <= max_abs_mean
    assert est.resets == 0
    # far better than ignoring y: the truth's own spread is ~24 deg
    assert e.std() < 0.35 * traces[alpha].theta[BURN_IN:].std()


@pytest.mark.parametrize("alpha", [1.0, 0.3])
def test_std_is_calibrated(traces, runs, alpha):
    """theta_std_deg is honest: |error| < 2 sigma in 92-99 % of steps, < 1 sigma in 62-85 %."""
    th, sd, _ = runs[alpha]
    e = np.abs(th[BURN_IN:] - traces[alpha].theta[BURN_IN:])
    s = sd[BURN_IN:]
    assert 0.92 <= np.mean(e < 2 * s) <= 0.99
    assert 0.62 <= np.mean(e < s) <= 0.85
    # and it tracks the situation: larger when the error is larger
    big = e > np.percentile(e, 90)
    assert s[big].mean() > s[~big].mean()


def test_outputs_always_finite_and_in_range(runs):
    for th, sd, _ in runs.values():
        assert np.all(np.isfinite(th)) and np.all(np.isfinite(sd))
        assert th.min() >= 0.0 and th.max() <= 90.0
        assert sd.min() >= 0.3 and sd.max() <= 51.0


def test_eq3_propagation_is_exact():
    """One prediction step equals vecu.plant.throttle.step_mean (eq. 3) + clip, all classes."""
    est = ThrottleParticleFilter(1.0, n_high=64, n_low=64, use_kalman=False)
    est._ztab[:2] = 0.0  # no theta noise, the prior current
    rng = np.random.default_rng(0)
    for lo, hi in [(0.0, 40.0), (20.0, 89.0), (1.5, 7.9), (8.1, 15.9), (0.0, 0.99)]:
        f = est._b.cur
        f.th[:] = rng.uniform(lo, hi, f.th.size)
        f.rh[:] = rng.normal(0.0, 50.0, f.rh.size)
        f.rh[:3] = 0.0  # sgn(0) = 0 in eq. 3
        f.ci[:] = rng.normal(2.0, 2.0, f.ci.size)
        f.w[:] = 1.0
        est._adopt(f)
        x0 = f.F[:3].copy()
        est.step(3.7, None)
        ref = np.array([step_mean(*x0[:, j], 3.7) for j in range(x0.shape[1])]).T
        ref[0] = np.clip(ref[0], 0.0, 90.0)
        np.testing.assert_allclose(est._b.cur.F[:3], ref, rtol=0, atol=1e-12)


def test_class_matrices_are_table_i():
    m = class_matrix_stack()
    p3 = TABLE_I[2]
    assert m[9 + 1, 2] == p3.a23 and m[9 + 2, 1] == p3.a32 and m[9 + 1, 4] == p3.c1


def test_kalman_moments_match_numpy():
    """The Kalman stretch's unrolled algebra equals A P A^T + Q and the Gaussian i^2 update."""
    p = TABLE_I[2]
    a = np.array([[1.0, p.a12, 0.0], [p.a21, p.a22, p.a23], [0.0, p.a32, p.a33]])
    q = np.diag([0.35, 0.0, 0.18])
    rng = np.random.default_rng(1)
    m = rng.normal(size=(3, 3))
    cov = m @ m.T + np.eye(3)
    mean = np.array([50.0, 1.0, 3.0])
    s = new_state()[1]
    set_constants(s, 0.35, 0.18)
    x0 = (*mean, cov[0, 0], cov[0, 1], cov[0, 2], cov[1, 1], cov[1, 2], cov[2, 2])
    x = mode3_predict(x0, tuple(s.kf_coef.tolist()), 0.35, 0.18, 5.0)
    pp = a @ cov @ a.T + q

    def cov_of(x):
        return np.array([[x[3], x[4], x[5]], [x[4], x[6], x[7]], [x[5], x[7], x[8]]])

    np.testing.assert_allclose(cov_of(x), pp, rtol=1e-12)
    th, rh, ci = step_mean(50.0, 1.0, 3.0, 5.0)
    rh += p.c1 * (math.erf(1.0 / math.sqrt(2.0 * cov[1, 1])) - 1.0)  # E[sgn rho], not sgn
    assert abs(x[0] - th) < 1e-12 and abs(x[2] - ci) < 1e-12 and abs(x[1] - rh) < 1e-12
    mi, vi = x[2], x[8]
    s = 4 * mi * mi * vi + 2 * vi * vi + 1.0  # Var[i^2] + R under N(mi, vi)
    k = 2 * mi * pp[:, 2] / s
    np.testing.assert_allclose(cov_of(mode3_update(x, 10.0 - mi * mi - vi, s)),
                               pp - np.outer(k, k) * s, rtol=1e-9, atol=1e-12)


def test_bad_measurements_are_rejected_and_never_nan():
    tr = simulate(6000, seed=3, noise_scale=1.0)
    est = make_production_estimator(1.0)
    bad = [math.nan, math.inf, -math.inf, 1e9, -1e9, 3e3, -60.0]
    up = 0.0
    for k in range(len(tr.y)):
        y = tr.y[k] if k % 7 else bad[(k // 7) % len(bad)]
        est.step(up, y)
        assert math.isfinite(est.theta_deg) and 0.0 <= est.theta_deg <= 90.0
        assert math.isfinite(est.theta_std_deg) and est.theta_std_deg > 0.0
        up = tr.u[k]
    assert est.rejected >= len(tr.y) // 7 - 1
    assert est.resets == 0
    # rejected readings must not wreck the estimate: still tracking the truth
    th_hat = est.theta_deg
    assert abs(th_hat - tr.theta[-1]) < 30.0


def test_isolated_plausible_outlier_is_gated():
    """An in-range but impossible reading (900 W = 30 A while i ~ 3 A) is rejected, not used."""
    tr = simulate(3000, seed=4, noise_scale=1.0)
    clean, spiked = make_production_estimator(1.0), make_production_estimator(1.0)
    up = 0.0
    diff = []
    for k in range(len(tr.y)):
        clean.step(up, tr.y[k])
        spiked.step(up, 900.0 if k == 2500 else tr.y[k])
        if k >= 2500:
            diff.append(abs(spiked.theta_deg - clean.theta_deg))
        up = tr.u[k]
    assert spiked.rejected == clean.rejected + 1
    assert spiked.resets == 0
    assert max(diff) < 5.0 and np.mean(diff) < 2.0


def test_bad_input_voltage_is_survived():
    est = make_production_estimator(1.0)
    for u in (math.nan, math.inf, -math.inf, 1e12, -1e12, 5.0):
        est.step(u, 4.0)
        assert math.isfinite(est.theta_deg) and math.isfinite(est.theta_std_deg)


def test_missing_frames_predict_only(traces):
    """y = None: prediction only; the std grows while blind, the estimate recovers after."""
    tr = traces[1.0]
    est = make_production_estimator(1.0)
    up = 0.0
    sd_before = sd_blind = 0.0
    rej_before = rej_blind = -1
    errs = []
    for k in range(12_000):
        blind = 8000 <= k < 8500
        est.step(up, None if blind else tr.y[k])
        if k == 7999:
            sd_before, rej_before = est.theta_std_deg, est.rejected
        if k == 8499:
            sd_blind, rej_blind = est.theta_std_deg, est.rejected
        if k >= 9500:
            errs.append(est.theta_deg - tr.theta[k])
        up = tr.u[k]
    assert sd_blind > sd_before
    assert rej_blind == rej_before  # a missing frame is not a rejected one
    assert est.resets == 0
    assert np.std(errs) < 9.0


def test_divergence_resets_and_recovers():
    tr = simulate(4000, seed=5, noise_scale=1.0)
    est = ThrottleParticleFilter(1.0, use_kalman=False)
    up = 0.0
    for k in range(len(tr.y)):
        if k == 1000:
            est._b.cur.w[:] = np.nan  # corrupt the filter
        est.step(up, tr.y[k])
        assert math.isfinite(est.theta_deg) and math.isfinite(est.theta_std_deg)
        up = tr.u[k]
    assert est.resets == 1


def test_deterministic_and_reset_replays(traces, backend):
    tr = traces[1.0]
    tr_u, tr_y = tr.u[:6000], tr.y[:6000]

    def outputs(est):
        out, up = [], 0.0
        for k in range(len(tr_y)):
            est.step(up, tr_y[k])
            out.append((est.theta_deg, est.theta_std_deg))
            up = tr_u[k]
        return out

    a, b = ThrottleParticleFilter(1.0, seed=7), ThrottleParticleFilter(1.0, seed=7)
    first = outputs(a)
    assert first == outputs(b)
    a.reset()
    assert outputs(a) == first
    assert outputs(ThrottleParticleFilter(1.0, seed=8)) != first


def test_registry_and_protocol():
    est = make_throttle_estimator("production", 0.3)
    assert est.name == "production" and est.resets == 0
    est.step(0.0, None)
    est.step(2.0, 1.0)
    assert isinstance(est.theta_deg, float) and isinstance(est.theta_std_deg, float)
    est.reset()
    assert est.resets == 0


def test_outlier_redo_uses_the_prior_mode_classes(backend):
    """A redone step (isolated outlier -> predict only) must pick each particle's eq. (3) mode
    from where that particle *was*, exactly as a plain predict-only step does. Particles that
    straddle 16 deg (mode 2 | mode 3) and all move above it are the case where taking the
    classes from the first attempt's predicted extent would give wrong dynamics."""
    runs = []
    for y in (None, 2000.0):  # 2000 W: in range, impossible for i ~ 1 A -> gated as an outlier
        est = ThrottleParticleFilter(1.0, use_kalman=False)
        f = est._b.cur
        n = f.th.size
        f.th[:] = np.linspace(15.0, 17.0, n)
        f.rh[:] = 6.0 / min(TABLE_I[1].a12, TABLE_I[2].a12)  # every theta' > 20 deg
        f.ci[:] = 1.0
        est._adopt(f)  # extent 15..17 deg: classes 2 and 3
        est.step(0.5, y)
        runs.append((est.theta_deg, est.theta_std_deg, est.rejected))
    assert runs[1][2] == runs[0][2] + 1  # the second one was treated as an outlier
    assert runs[1][:2] == runs[0][:2]


def _counter_peak(gate_exceeded: np.ndarray) -> int:
    """The TPS plausibility monitor's saturating up/down counter (limit 300) on a series."""
    c = peak = 0
    for bad in gate_exceeded.tolist():
        c = min(c + 1, 300) if bad else max(c - 1, 0)
        peak = max(peak, c)
    return peak


def test_stuck_below_the_mode3_bound_reports_a_wide_sigma(backend):
    """Issue 30 item 5 (docs/models.md, Consistency): the cause of the soak's false TPS DTCs,
    reproduced offline. On seed 18 at ~50.4 s the truth is thrown through 16 deg to ~60 deg
    (u 4.1 V) while the particles stay parked at 7-13 deg: with the posterior's std alone
    (lock_std_deg=0) sigma is 1.6-4 deg there and a perfect sensor is outside the TPS gate
    5 sigma + 15 deg on ~100 ticks in a row. The shipped filter reports the same estimate with
    LOCK_STD_DEG added where it is stuck-prone, and the sensor stays (nearly) inside the gate.
    (Both with the 1000 particles of the soak's filter: the episode is this draw's.)"""
    n = 50_800
    tr = simulate(n, seed=18, noise_scale=1.0)
    th0, sd0 = _run(ThrottleParticleFilter(1.0, n_low=1000, lock_std_deg=0.0), tr)
    th, sd = _run(ThrottleParticleFilter(1.0, n_low=1000), tr)
    assert np.array_equal(th, th0)  # only the reported std differs
    err = np.abs(th - tr.theta)
    u_prev = np.concatenate(([0.0], tr.u[:-1]))
    stuck_prone = (th <= 17.5) & (u_prev > 3.0)
    assert np.array_equal(sd > sd0, stuck_prone)
    assert np.all(sd[stuck_prone] >= 12.0) and np.array_equal(sd[~stuck_prone], sd0[~stuck_prone])
    window = slice(50_400, 50_700)
    confident_wrong = (err[window] > 5 * sd0[window] + 15) & (sd0[window] < 5)
    assert confident_wrong.sum() >= 50  # the cause: wrong by 20-50 deg with sigma < 5
    assert _counter_peak(err > 5 * sd0 + 15) >= 60
    assert _counter_peak(err > 5 * sd + 15) <= 15
    # the reported sigma is honest where it was widened (NEES near 1, was > 10)
    m = stuck_prone.copy()
    m[:BURN_IN] = False
    assert np.mean((err[m] / sd0[m]) ** 2) > 10
    assert 0.3 < np.mean((err[m] / sd[m]) ** 2) < 3
