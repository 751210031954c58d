"""Intake-manifold plant (Dutka 2006, corrected): steady states, flows, actuator, stability."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from vecu.bench.estimators import euler_event, manifold_rhs
from vecu.models.manifold import (
    critical_pressure_ratio,
    cylinder_air_charge,
    event_coefficients,
    f,
    flow_function,
    integrate_manifold,
    nominal_input,
    port_flow,
    psi_choked,
    sample_time,
    steady_state,
    steady_state_vector,
    throttle_flow,
    volumetric_efficiency,
)
from vecu.models.manifold_integrator import tables
from vecu.models.manifold_params import V8_5L7, EngineInput
from vecu.plant.drive_profile import DriveProfile, DriveProfileConfig, us06_like
from vecu.plant.manifold import (
    ManifoldPlantConfig,
    ManifoldTrace,
    measure,
    plant_constants,
    plant_step,
    simulate,
)
from vecu.rng import rng_streams

P = V8_5L7
SEEDS = (0, 1, 2)
DEG = math.pi / 180.0
NOISE_FREE = ManifoldPlantConfig(noise_scale=0.0)


def actuator_coeffs(ts: float) -> tuple[float, float, float, float]:
    """(a1, a2, b1, b2) of the corrected eq. 1."""
    return event_coefficients(ts, P.zeta, P.omega0, P.tau_temp_s)[:4]


def actuator_coeffs_printed(ts: float, params=P) -> tuple[float, float, float, float]:
    """(a1, a2, b1, b2) exactly as printed under eq. 1 (wrong; the evidence)."""
    zw = params.zeta * params.omega0
    w_et = params.omega0 * math.sqrt(1.0 - params.zeta * params.zeta)
    a = math.exp(-zw * ts)
    b = math.cos(w_et * ts)
    g = math.sin(w_et * ts)
    return -2.0 * a * a * b, a * a, 1.0 - a * (b + zw * g / w_et), a * a + a * (zw * g / (w_et - b))


def _step(x: np.ndarray, u: EngineInput, dt: float | None = None) -> None:
    """One noise-free event of the truth (plant_step) on x, in place."""
    ts = sample_time(u.n_rpm, P.n_cyl) if dt is None else dt
    plant_step(x, u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool, ts, np.zeros(7),
               plant_constants(P, NOISE_FREE, 0.0, 0.0), *tables(P))


def _stepped(profile, seed, params, config) -> ManifoldTrace:
    """simulate event by event in Python (the oracle of truth_events): the profile's own
    lookup, the measurement and plant_step per event, the stream's noise rows in blocks."""
    rng = rng_streams(seed, ("manifold.plant",))["manifold.plant"]
    n0, sp0 = profile.at(0.0)
    st = steady_state_vector(nominal_input(sp0, n0, params), params)
    pc = plant_constants(params, config, 0.0, 0.0)
    rows, xs, ys = [], [], []
    noise, pos, t = np.empty((0, 7)), 0, 0.0
    while t < profile.duration_s:
        if pos == len(noise):
            noise, pos = rng.standard_normal((config.block, 7)), 0
        w = noise[pos]
        pos += 1
        n, sp = profile.at(t)
        u = nominal_input(sp, n, params)
        ts = sample_time(n, params.n_cyl)
        xs.append(st.copy())
        ys.append(measure(st, w, pc))
        flows = (throttle_flow(st[1], st[3], u.p_a, u.t_a, params)[0],
                 port_flow(st[3], st[4], n, params), cylinder_air_charge(st[3], st[4], n, params))
        m = plant_step(st, sp, n, u.p_a, u.t_a, u.t_cool, ts, w, pc, *tables(params))
        rows.append((t, ts, n, sp, *flows, float(m)))
        t += ts
    a = np.array(rows)
    return ManifoldTrace(t=a[:, 0], ts=a[:, 1], n_rpm=a[:, 2], ta_sp=a[:, 3], x=np.array(xs),
                         y=np.array(ys), mdot_at=a[:, 4], mdot_ac=a[:, 5], cac=a[:, 6],
                         substeps=a[:, 7].astype(int))


def _ss(deg: float, n: float) -> tuple[float, float]:
    return steady_state(deg * DEG, nominal_input(deg * DEG, n))


@pytest.fixture(scope="module")
def runs():
    """80 s profile and noisy plant run (paper's Q and R) for each seed."""
    return {s: (us06_like(s), simulate(us06_like(s), seed=s)) for s in SEEDS}


# ----------------------------------------------------------------------------- steady states

def test_idle_pressure_is_plausible_for_a_v8():
    p, t = _ss(7.5, 700)
    assert 25.0 <= p <= 45.0
    assert 305.0 < t < 330.0  # warmed by coolant and ambient heat at the low idle flow
    mdot, _ = throttle_flow(7.5 * DEG, p, P.p_a_kpa, P.t_a_k)
    assert 4.5e-3 < mdot < 7.5e-3  # a few g/s of air at a V8 idle


def test_wide_open_throttle_is_ambient_minus_the_throttle_drop():
    lo_speed, _ = _ss(90.0, 700)
    hi_speed, _ = _ss(90.0, 5600)
    assert 99.0 < lo_speed < P.p_a_kpa
    assert 95.0 < hi_speed < lo_speed  # more flow, larger drop
    assert P.p_a_kpa - hi_speed < 5.0


@pytest.mark.parametrize("n", [700.0, 1500.0, 2500.0, 3500.0, 4500.0, 5600.0])
def test_manifold_pressure_range_between_floor_and_wot(n):
    floor = P.throttle_floor_rad(n)
    p_floor, _ = steady_state(floor, nominal_input(floor, n))
    p_wot, _ = _ss(90.0, n)
    assert 15.0 < p_floor < 45.0
    assert 95.0 < p_wot < 100.0
    for deg in (20.0, 30.0, 45.0, 60.0):  # pressure rises with the opening
        if deg * DEG > floor:
            p_mid, _ = _ss(deg, n)
            assert p_floor < p_mid < p_wot


@pytest.mark.parametrize("deg,n", [(7.5, 700.0), (15.0, 2000.0), (30.0, 3000.0), (90.0, 700.0),
                                   (90.0, 5600.0), (22.0, 5600.0)])
def test_dynamic_steady_state_conserves_mass(deg, n):
    """Integrated from far away, the event model settles where throttle flow = port flow."""
    u = nominal_input(deg * DEG, n)
    p, t = 60.0, 290.0
    ts = sample_time(n)
    for _ in range(int(3.0 / ts)):
        p, t, _ = integrate_manifold(p, t, deg * DEG, u, ts)
    p_ss, t_ss = steady_state(deg * DEG, u)
    assert p == pytest.approx(p_ss, abs=1e-3)
    assert t == pytest.approx(t_ss, abs=1e-3)
    m_at, _ = throttle_flow(deg * DEG, p, u.p_a, u.t_a)
    m_ac = port_flow(p, t, n)
    assert m_at == pytest.approx(m_ac, rel=1e-3)
    dp, dt = manifold_rhs(p_ss, t_ss, deg * DEG, u)
    assert abs(dp) < 1e-6 and abs(dt) < 1e-6


def test_steady_temperature_is_enthalpy_balance():
    """At rest: c_p mdot (T_im - T_a) = Q_ext(T_im) (energy balance behind eq. 5-6)."""
    for deg, n in ((7.5, 700.0), (30.0, 3000.0), (90.0, 5600.0)):
        p, t = _ss(deg, n)
        mdot = port_flow(p, t, n)
        cp = P.kappa * P.r_air / (P.kappa - 1.0)
        q = P.h1_w_per_k * (P.t_cool_k - t) + P.h2_w_per_k * (P.t_a_k - t)
        assert cp * mdot * (t - P.t_a_k) == pytest.approx(q, rel=1e-9, abs=1e-9)


def test_volumetric_efficiency_map_range():
    vals = [volumetric_efficiency(n, p)[0] for n in (500, 700, 2000, 3750, 5600, 6500)
            for p in (15.0, 25.0, 50.0, 100.0)]
    assert 0.45 < min(vals) and max(vals) < 0.93


# ----------------------------------------------------------------------------- throttle flow

def test_choked_flow_function_corrected():
    assert psi_choked(1.4) == pytest.approx(0.6847, abs=1e-4)
    printed = math.sqrt(1.4) * (2.0 / 0.4) ** (2.4 / 0.8)  # 2/(kappa-1) as printed in eq. 3
    assert printed == pytest.approx(147.9, abs=0.1)


def test_choked_nonchoked_continuity():
    pr_c = critical_pressure_ratio(P.kappa)
    assert pr_c == pytest.approx(0.5283, abs=1e-4)
    lo, dlo = flow_function(pr_c - 1e-9)
    hi, dhi = flow_function(pr_c + 1e-9)
    assert lo == pytest.approx(hi, abs=1e-8)
    assert abs(dlo) < 1e-3 and abs(dhi) < 1e-3  # psi has its maximum at the choking boundary
    for deg in (7.5, 30.0, 90.0):
        a = deg * DEG
        m1, _ = throttle_flow(a, pr_c * P.p_a_kpa * (1 - 1e-9), P.p_a_kpa, P.t_a_k)
        m2, _ = throttle_flow(a, pr_c * P.p_a_kpa * (1 + 1e-9), P.p_a_kpa, P.t_a_k)
        assert m1 == pytest.approx(m2, rel=1e-7)


def test_flow_function_regularised_near_unity():
    pr = np.linspace(critical_pressure_ratio(P.kappa), 1.0, 4001)
    psi = np.array([flow_function(x)[0] for x in pr])
    assert np.all(np.diff(psi) < 0.0)  # monotone from the choked maximum down to 0
    assert psi[-1] == pytest.approx(0.0, abs=1e-12)
    r = P.pr_reg
    for k in (0, 1):  # C1 at the switch to the quadratic
        a, b = flow_function(r - 1e-9)[k], flow_function(r + 1e-9)[k]
        assert a == pytest.approx(b, rel=1e-5)
    slopes = [flow_function(x)[1] for x in np.linspace(r, 1.0, 50)]
    assert max(abs(s) for s in slopes) < 20.0  # finite slope up to pr = 1


def test_throttle_flow_derivative_matches_finite_difference():
    for deg in (7.5, 30.0, 60.0, 90.0):
        for p in (40.0, 70.0, 90.0, 97.0, 99.5):
            _, dm = throttle_flow(deg * DEG, p, 100.0, 298.15)
            e = 1e-6
            fd = (throttle_flow(deg * DEG, p + e, 100.0, 298.15)[0]
                  - throttle_flow(deg * DEG, p - e, 100.0, 298.15)[0]) / (2 * e)
            assert dm == pytest.approx(fd, rel=1e-4, abs=1e-9)


# ----------------------------------------------------------------------------- actuator, eq. 1

def test_corrected_actuator_matches_continuous_step_response():
    zw = P.zeta * P.omega0
    wd = P.omega0 * math.sqrt(1 - P.zeta ** 2)
    for n in (700.0, 3000.0, 5600.0):
        ts = sample_time(n)
        a1, a2, b1, b2 = actuator_coeffs(ts)
        th, th_prev, u_prev = 0.0, 0.0, 0.0
        worst = 0.0
        for k in range(1, int(0.4 / ts)):
            th, th_prev, u_prev = a1 * th + a2 * th_prev + b1 * 1.0 + b2 * u_prev, th, 1.0
            t = k * ts
            exact = 1 - math.exp(-zw * t) * (math.cos(wd * t) + zw / wd * math.sin(wd * t))
            worst = max(worst, abs(th - exact))
        assert worst < 1e-9
        assert (b1 + b2) / (1 - a1 - a2) == pytest.approx(1.0, abs=1e-12)


def test_printed_actuator_is_wrong():
    def spectral_radius(c):
        a1, a2, _, b2 = c
        return max(abs(np.linalg.eigvals(np.array([[0, 0, 0], [b2, a1, a2], [0, 1, 0]]))))

    printed = actuator_coeffs_printed(sample_time(6000.0))
    assert spectral_radius(printed) > 2.0  # unstable
    a1, a2, b1, b2 = actuator_coeffs_printed(sample_time(700.0))
    assert abs((b1 + b2) / (1 - a1 - a2) - 1.0) > 0.2  # wrong DC gain
    for n in (700.0, 6000.0):
        assert spectral_radius(actuator_coeffs(sample_time(n))) < 1.0


# ----------------------------------------------------------------------------- integration

def test_single_euler_step_diverges_where_substepping_does_not():
    u = nominal_input(60 * DEG, 1500.0)
    p_ss, t_ss = steady_state(60 * DEG, u)
    p_e, t_e = p_ss - 1.0, t_ss
    p_i, t_i = p_ss - 1.0, t_ss
    for _ in range(20):
        p_e, t_e = euler_event(p_e, t_e, 60 * DEG, u)
        p_i, t_i, _ = integrate_manifold(p_i, t_i, 60 * DEG, u, sample_time(1500.0))
    assert not (abs(p_e - p_ss) < 1.0)  # printed eq. 5 (one Euler step per event) blows up
    assert abs(p_i - p_ss) < 1e-3


@pytest.mark.parametrize("n", [700.0, 1500.0, 3000.0, 4500.0, 5600.0])
def test_stable_over_the_whole_operating_range(n):
    """Closed (0 deg) to wide open, from both ends of the pressure range: finite and settling."""
    ts = sample_time(n)
    for deg in (0.0, 2.0, 7.5, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0):
        u = nominal_input(deg * DEG, n)
        for p0, t0 in ((15.0, 260.0), (100.0, 380.0)):
            p, t = p0, t0
            for _ in range(int(3.0 / ts)):
                p, t, m = integrate_manifold(p, t, deg * DEG, u, ts)
                assert math.isfinite(p) and math.isfinite(t) and 1 <= m <= P.max_substeps
                assert 0.0 < p < P.p_a_kpa + 1.0 and 200.0 < t < 450.0
            if deg >= 7.5:
                p_ss, _ = steady_state(deg * DEG, u)
                assert p == pytest.approx(p_ss, abs=0.01)


def test_step_accepts_a_long_interval():
    u = nominal_input(90 * DEG, 700.0)
    x0 = steady_state_vector(nominal_input(7.5 * DEG, 700.0))
    x0[1] = x0[2] = 90 * DEG  # throttle already open, manifold still at idle pressure
    _step(x0, u, dt=0.25)
    p_ss, _ = steady_state(90 * DEG, u)
    assert x0[3] == pytest.approx(p_ss, abs=0.05)


def test_substepping_agrees_with_a_fine_reference():
    """Event integrator vs RK4 at 50 us on a 3 s window with the WOT launch (noise-free)."""
    prof = us06_like(1)
    tr = simulate(prof, seed=1, config=ManifoldPlantConfig(noise_scale=0.0))
    k0 = int(np.searchsorted(tr.t, 1.0))
    k1 = int(np.searchsorted(tr.t, 4.0))
    assert np.ptp(tr.x[k0:k1, 3]) > 50.0  # the window really contains a snap
    p, t = tr.x[k0, 3], tr.x[k0, 4]
    err_p, err_t = [], []
    for k in range(k0, k1):
        err_p.append(tr.x[k, 3] - p)
        err_t.append(tr.x[k, 4] - t)
        u, a = nominal_input(tr.ta_sp[k], tr.n_rpm[k]), tr.x[k, 1]
        m = math.ceil(tr.ts[k] / 50e-6)
        hh = tr.ts[k] / m
        for _ in range(m):
            k1p, k1t = manifold_rhs(p, t, a, u)
            k2p, k2t = manifold_rhs(p + hh / 2 * k1p, t + hh / 2 * k1t, a, u)
            k3p, k3t = manifold_rhs(p + hh / 2 * k2p, t + hh / 2 * k2t, a, u)
            k4p, k4t = manifold_rhs(p + hh * k3p, t + hh * k3t, a, u)
            p += hh / 6 * (k1p + 2 * k2p + 2 * k3p + k4p)
            t += hh / 6 * (k1t + 2 * k2t + 2 * k3t + k4t)
    assert math.sqrt(np.mean(np.square(err_p))) < 0.05  # kPa
    assert math.sqrt(np.mean(np.square(err_t))) < 0.3  # K
    assert max(abs(e) for e in err_p) < 0.5


# ----------------------------------------------------------------------------- 80 s profile

def test_profile_shape():
    cfg = DriveProfileConfig()
    for s in SEEDS:
        prof = us06_like(s)
        assert prof.duration_s == pytest.approx(cfg.duration_s)
        assert prof.n_rpm.min() == pytest.approx(P.n_idle_rpm)
        assert prof.n_rpm.max() == pytest.approx(P.n_max_rpm)
        floor = np.array([P.throttle_floor_rad(n) for n in prof.n_rpm])
        assert np.all(prof.ta_sp >= floor - 1e-12) and prof.ta_sp.max() <= 90 * DEG + 1e-12
        assert prof.ta_sp.max() == pytest.approx(90 * DEG)  # wide open at least once
        jumps = np.abs(np.diff(prof.ta_sp))
        assert jumps.max() > 40 * DEG and np.sum(jumps > 10 * DEG) >= 5  # snaps, not ramps


def test_profile_is_seeded():
    a, b, c = us06_like(7), us06_like(7), us06_like(8)
    assert np.array_equal(a.n_rpm, b.n_rpm) and np.array_equal(a.ta_sp, b.ta_sp)
    assert not np.array_equal(a.n_rpm, c.n_rpm)


@pytest.mark.parametrize("seed", SEEDS)
def test_stable_over_the_80s_profile(runs, seed):
    _, tr = runs[seed]
    assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.y))
    p, t = tr.x[:, 3], tr.x[:, 4]
    assert p.min() > 15.0 and p.max() < 105.0
    assert p.max() > 97.0  # wide open reached
    assert 240.0 < t.min() and t.max() < 400.0
    assert 295.0 < float(np.median(t)) < 320.0
    alpha = tr.x[:, 1]
    assert alpha.min() > 5 * DEG and alpha.max() < 93 * DEG  # overshoot (1.5 % at zeta 0.8) + noise
    cac = tr.cac * 1e6  # mg per cylinder
    assert 40.0 < cac.min() and cac.max() < 800.0


@pytest.mark.parametrize("seed", SEEDS)
def test_event_timing(runs, seed):
    prof, tr = runs[seed]
    assert np.allclose(tr.ts, 120.0 / (8.0 * tr.n_rpm), rtol=0, atol=1e-15)
    assert np.allclose(np.diff(tr.t), tr.ts[:-1], rtol=0, atol=1e-12)
    assert tr.t[0] == 0.0 and tr.t[-1] < prof.duration_s <= tr.t[-1] + tr.ts[-1]
    idx = np.linspace(0, len(tr.t) - 1, 50).astype(int)
    for i in idx:
        assert prof.at(float(tr.t[i])) == (tr.n_rpm[i], tr.ta_sp[i])
    assert tr.ts.min() == pytest.approx(120 / (8 * 5600.0), rel=1e-3)
    assert tr.ts.max() == pytest.approx(120 / (8 * 700.0))


def test_simulation_is_deterministic(runs):
    prof, tr = runs[0]
    again = simulate(prof, seed=0)
    for field in dataclasses.fields(tr):
        assert np.array_equal(getattr(tr, field.name), getattr(again, field.name)), field.name
    other = simulate(prof, seed=1)
    assert not np.array_equal(tr.y, other.y)


def test_measurement_and_process_noise_match_section_iv(runs):
    _, tr = runs[0]
    res = tr.y - tr.x[:, [1, 3, 5]]
    assert np.std(res, axis=0) == pytest.approx(np.sqrt([7.62e-5, 1e-2, 2.5e-3]), rel=0.05)


def test_f_is_the_noise_free_plant_step():
    u0 = nominal_input(20 * DEG, 2500.0)
    x = steady_state_vector(u0)
    st = x.copy()
    for sp_deg, n in ((60.0, 2600.0), (60.0, 2700.0), (10.0, 2800.0), (90.0, 3000.0)):
        u = EngineInput(sp_deg * DEG, n)
        x = f(x, u)
        _step(st, u)
        assert np.array_equal(x, st)
    # steady state is a fixed point of the event map
    xs = steady_state_vector(u0)
    assert np.allclose(f(xs, u0), xs, rtol=0, atol=1e-9)


def test_any_noise_scale_the_parameter_tree_admits_stays_finite():
    """Issue 14 item 3: plant.manifold.noise_scale up to the tree's bound (1e3) must run; at 300
    the noise drove T_im below 0 K and the event integrator raised on NaN."""
    p = us06_like(0)
    head = DriveProfile(p.dt_s, p.n_rpm[:1001], p.ta_sp[:1001])  # the first 10 s
    tr = simulate(head, seed=0, config=ManifoldPlantConfig(noise_scale=1e3))
    assert np.all(np.isfinite(tr.x)) and np.all(np.isfinite(tr.y)) and np.all(np.isfinite(tr.cac))
    assert tr.x[:, 3].min() >= 5.0 and 150.0 <= tr.x[:, 4].min() and tr.x[:, 4].max() <= 1000.0


def test_simulation_is_the_event_by_event_loop(backend):
    """simulate's loop as one kernel (plant.manifold.truth_events) gives the event-by-event
    loop of the plant's kernels (_stepped) bit for bit, with a perturbed engine and sensor gain
    errors."""
    p = us06_like(2)
    k = round(10.0 / p.dt_s) + 1
    prof = DriveProfile(p.dt_s, p.n_rpm[:k], p.ta_sp[:k])
    eng = dataclasses.replace(V8_5L7, zeta=V8_5L7.zeta * 1.04, h1_w_per_k=V8_5L7.h1_w_per_k * 0.97)
    cfg = ManifoldPlantConfig(engine=eng, sensor_gains=(1.03, 0.98, 1.01), block=100)
    ref = _stepped(prof, 2, eng, cfg)
    got = simulate(prof, seed=2, params=eng, config=cfg)
    for fld in dataclasses.fields(ref):
        a, b = getattr(ref, fld.name), getattr(got, fld.name)
        assert a.shape == b.shape and np.array_equal(a, b), fld.name
    assert len(ref.t) > 2000 and np.ptp(ref.x[:, 3]) > 30.0
