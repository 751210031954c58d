"""The manifold plant's whole simulation over a drive profile as one compiled kernel.

`simulate_events` is vecu.plant.manifold.simulate's event loop (profile lookup, the measurement
with the paper's R and the sensor gains, the truth's throttle flow, port flow and air charge,
ManifoldPlant.step: eq. 1, the event integrator of eq. 5-6, eq. 9, Section IV's Q, the physical
clamps) in the same floating-point operations and order, over noise rows drawn beforehand from
the same stream (Generator.standard_normal fills rows in order, so drawing them at once or in
blocks gives the same numbers). Under the numba backend `simulate` runs it (bit-identical to the
Python loop: tests/plant/test_manifold.py); the Python backend never does.
"""

# ruff: noqa: FURB136 (x if c else y mirrors Python's min()/max(), NaN included)
from __future__ import annotations

from vecu.kernels import kernel
from vecu.models.manifold import air_charge_of, event_coefficients, port_flow_of, throttle_flow_of
from vecu.models.manifold_integrator import _integrate_event

# plant constants vector (simulate_events' pc)
(C_ZETA, C_OMEGA0, C_TAU, C_VCYL, C_NCYL, C_PA, C_TA, C_TCOOL, C_SQ0, C_SQ1, C_SQ2, C_SQ3,
 C_SR0, C_SR1, C_SR2, C_G0, C_G1, C_G2, C_PMIN, C_PMAX, C_TMIN, C_TMAX, C_DURATION,
 C_DT) = range(24)
N_PLANT_CONSTS = 24


@kernel
def profile_at(prof_n, prof_sp, dt_p, time):
    """DriveProfile.at(time): (N interpolated linearly, the setpoint held)."""
    last = len(prof_n) - 1
    fx = time / dt_p
    fx = 0.0 if 0.0 > fx else fx
    fx = float(last) if float(last) < fx else fx
    i = int(fx)
    i = last - 1 if last - 1 < i else i
    frac = fx - i
    n = prof_n[i] + frac * (prof_n[i + 1] - prof_n[i])
    return n, prof_sp[i if frac < 1.0 else i + 1]


@kernel
def plant_step(st, sp, n, ts, w, pc, cst, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """ManifoldPlant.step in place on st = (u_prev, alpha, alpha_prev, P_im, T_im, T_meas):
    eq. 1 (actuator_coeffs), the event integrator of eq. 5-6, eq. 9 (iat_coeffs), Section IV's
    Q from noise row w and the physical clamps; returns the sub-steps used."""
    u_prev, alpha, alpha_prev, p, t, tm = st[0], st[1], st[2], st[3], st[4], st[5]
    a1, a2, b1, b2, a_t, b_t = event_coefficients(ts, pc[C_ZETA], pc[C_OMEGA0], pc[C_TAU])
    p_n, t_n, m = _integrate_event(p, t, alpha, pc[C_PA], pc[C_TA], pc[C_TCOOL], n, ts, cst,
                                   cd_alpha, cd_table, prs, eta_rpm, eta_val)
    new_alpha = a1 * alpha + a2 * alpha_prev + b1 * sp + b2 * u_prev + pc[C_SQ0] * w[0]
    v = p_n + pc[C_SQ1] * w[1]
    v = pc[C_PMIN] if pc[C_PMIN] > v else v
    new_p = pc[C_PMAX] if pc[C_PMAX] < v else v
    v = t_n + pc[C_SQ2] * w[2]
    v = pc[C_TMIN] if pc[C_TMIN] > v else v
    new_t = pc[C_TMAX] if pc[C_TMAX] < v else v
    v = a_t * tm + b_t * t + pc[C_SQ3] * w[3]
    v = pc[C_TMIN] if pc[C_TMIN] > v else v
    new_tm = pc[C_TMAX] if pc[C_TMAX] < v else v
    st[0], st[1], st[2], st[3], st[4], st[5] = sp, new_alpha, alpha, new_p, new_t, new_tm
    return m


@kernel
def simulate_events(x0, prof_n, prof_sp, noise, pc, cst, cd_alpha, cd_table, prs, eta_rpm,
                    eta_val, rows, xs, ys):
    """Events of the drive into rows (t, ts, N, TA_SP, mdot_at, mdot_ac, CAC, sub-steps), xs
    (state before the step) and ys (measurement); returns the number of events, or -1 when the
    output arrays (or noise rows) are too short."""
    ncyl = pc[C_NCYL]
    p_a, t_a = pc[C_PA], pc[C_TA]
    st = x0.copy()
    time = 0.0
    k = 0
    cap = min(len(xs), len(noise))
    while time < pc[C_DURATION]:
        if k >= cap:
            return -1
        n, sp = profile_at(prof_n, prof_sp, pc[C_DT], time)
        ts = 120.0 / (ncyl * n)
        w = noise[k]
        alpha, p, t, tm = st[1], st[3], st[4], st[5]
        for j in range(6):
            xs[k, j] = st[j]
        ys[k, 0] = (alpha + pc[C_SR0] * w[4]) * pc[C_G0]
        ys[k, 1] = (p + pc[C_SR1] * w[5]) * pc[C_G1]
        ys[k, 2] = (tm + pc[C_SR2] * w[6]) * pc[C_G2]
        mdot_at, _ = throttle_flow_of(alpha, p, p_a, t_a, cst, cd_alpha, cd_table, prs)
        mdot_ac = port_flow_of(n, p, t, cst, eta_rpm, eta_val)
        cac = air_charge_of(n, p, t, cst, pc[C_VCYL], eta_rpm, eta_val)
        m = plant_step(st, sp, n, ts, w, pc, cst, cd_alpha, cd_table, prs, eta_rpm, eta_val)
        rows[k, 0], rows[k, 1], rows[k, 2], rows[k, 3] = time, ts, n, sp
        rows[k, 4], rows[k, 5], rows[k, 6], rows[k, 7] = mdot_at, mdot_ac, cac, float(m)
        time += ts
        k += 1
    return k


# advance_events' out columns
(E_N, E_SP, E_TA, E_P, E_TM, E_P_TRUE, E_T_TRUE, E_CAC_TRUE) = range(8)


@kernel
def advance_events(st, t_ns, t0_ns, prof_n, prof_sp, noise, pos, pc, cst, cd_alpha, cd_table,
                   prs, eta_rpm, eta_val, times, out):
    """vecu.plant.node.ManifoldPart's events ahead, from the event at t_ns (ns, int) of the
    profile that started at t0_ns: per event k its time times[k] and out[k] = (N, TA_SP, the
    TA, P_im and T_im.out readings, the truth's P_im, T_im and CAC); st (the plant state) is
    advanced in place and noise rows are taken from pos on, one per event. The times are
    ManifoldPart's: t_{k+1} = t_k + max(1, round(T_s * 1e9)) ns. Stops before an event past the
    profile's end, when the noise rows run out or out is full; returns (events, the next event's
    time, the next noise row)."""
    ncyl = pc[C_NCYL]
    k = 0
    while k < len(out) and pos < len(noise):
        t_s = float(t_ns - t0_ns) / 1e9
        if t_s >= pc[C_DURATION]:
            break
        n, sp = profile_at(prof_n, prof_sp, pc[C_DT], t_s)
        w = noise[pos]
        p, t = st[3], st[4]
        times[k] = t_ns
        out[k, E_N], out[k, E_SP] = n, sp
        out[k, E_TA] = (st[1] + pc[C_SR0] * w[4]) * pc[C_G0]
        out[k, E_P] = (p + pc[C_SR1] * w[5]) * pc[C_G1]
        out[k, E_TM] = (st[5] + pc[C_SR2] * w[6]) * pc[C_G2]
        out[k, E_P_TRUE], out[k, E_T_TRUE] = p, t
        out[k, E_CAC_TRUE] = air_charge_of(n, p, t, cst, pc[C_VCYL], eta_rpm, eta_val)
        dt = 120.0 / (ncyl * n)
        plant_step(st, sp, n, dt, w, pc, cst, cd_alpha, cd_table, prs, eta_rpm, eta_val)
        pos += 1
        step_ns = round(dt * 1e9)
        t_ns += step_ns if step_ns > 1 else 1
        k += 1
    return k, t_ns, pos
