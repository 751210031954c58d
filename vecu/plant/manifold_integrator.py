"""The event integrator of eq. 5-6 (vecu.plant.manifold.integrate_manifold), written for speed.

It is the hot loop of every run: the plant steps it once per engine event, the ECU's filter once
and the 6-event air-charge prediction six times, each event ~15 sub-steps of two right-hand
sides. It computes exactly what the reference functions of vecu.plant.manifold compute
(`_rhs` = `throttle_flow` + `volumetric_efficiency` + `heat_flow`), in the same floating-point
operations and order (bit-identical results, tests/test_manifold_integrator.py), but:
- everything that is constant over one event is computed once per call: the throttle area and
  the C_d table column at the held angle alpha, Xi's factor, eta_N(N) and the pumping constant of
  the held input u, and the parameter set's constants (cached per ManifoldParams object);
- the sub-step loop is inlined in plain local floats (no calls per right-hand side);
- the second ROS2 stage skips the Jacobian terms it does not use.
"""

# ruff: noqa: FURB136 (x if c else y mirrors min()/max() exactly, NaN included, without a call)
from __future__ import annotations

import math
from bisect import bisect_right
from typing import TYPE_CHECKING

from vecu.plant.manifold_params import V8_5L7, ManifoldParams

if TYPE_CHECKING:
    from vecu.plant.manifold import EngineInput

P_FLOOR_KPA = 0.5  # lower guard for P_im inside eta and the integrator (never reached in use)
ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)

_CONSTS: dict[int, tuple[ManifoldParams, tuple]] = {}


def _interp_value(x: float, xs: tuple[float, ...], ys: tuple[float, ...]) -> float:
    """vecu.plant.manifold._interp's value (same operations)."""
    if x <= xs[0]:
        return ys[0]
    if x >= xs[-1]:
        return ys[-1]
    i = bisect_right(xs, x) - 1
    s = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i])
    return ys[i] + s * (x - xs[i])


def _param_consts(prm: ManifoldParams) -> tuple:
    """Per-parameter-set constants, computed as the reference functions compute them."""
    hit = _CONSTS.get(id(prm))
    if hit is not None and hit[0] is prm:
        return hit[1]
    k = prm.kappa
    c = 2.0 * k / (k - 1.0)
    e1 = 1.0 / k
    e2 = (k - 1.0) / k
    # C1 quadratic near pr = 1 (flow_function): psi and slope of eq. 2 at pr_reg
    pr_reg = prm.pr_reg
    inner = c * (1.0 - pr_reg ** e2)
    root = math.sqrt(inner)
    psi0 = pr_reg ** e1 * root
    dpsi0 = (e1 * pr_reg ** (e1 - 1.0) * root
             - pr_reg ** e1 * c * e2 * pr_reg ** (e2 - 1.0) / (2.0 * root))
    s0 = 1.0 - pr_reg
    d0 = -dpsi0
    qb = (d0 * s0 - psi0) / (s0 * s0)
    qa = d0 - 2.0 * qb * s0
    consts = (
        k, prm.r_air, prm.v_im_dm3, k - 1.0,
        (2.0 / (k + 1.0)) ** (k / (k - 1.0)),  # critical pressure ratio
        math.sqrt(k) * (2.0 / (k + 1.0)) ** ((k + 1.0) / (2.0 * (k - 1.0))),  # psi choked
        c, e1, e2, e1 - 1.0, e2 - 1.0, pr_reg, -s0, -psi0, qa, qb,
        prm.cd_pr, len(prm.cd_pr) - 2,
        prm.h1_w_per_k, prm.h2_w_per_k, prm.h1_w_per_k + prm.h2_w_per_k,
        prm.r_c, prm.p_exh_kpa, 1.0 / prm.kappa,
        prm.lam_dt_max, prm.dp_step_max_kpa, prm.dt_step_max_k, prm.max_substeps,
    )
    _CONSTS[id(prm)] = (prm, consts)
    return consts


def integrate_manifold(p_im: float, t_im: float, alpha: float, u: EngineInput, dt: float,
                       params: ManifoldParams = V8_5L7) -> tuple[float, float, int]:
    """Advance (P_im, T_im) by dt with alpha and u held; returns (P_im, T_im, M).

    See vecu.plant.manifold.integrate_manifold for the method (M ROS2 sub-steps with the
    diagonal Jacobian); this is its implementation.
    """
    (k, r, v, km1, prc, psic, c, e1, e2, e1m1, e2m1, pr_reg, ms0, mpsi0, qa, qb,
     prs, nseg, h1, h2, hsum, r_c, p_exh, e_eta, lam_max, dp_max, dt_max,
     max_sub) = _param_consts(params)
    prm = params
    p_a, t_a, t_cool, n_rpm = u.p_a, u.t_a, u.t_cool, u.n_rpm
    # --- per event: throttle (eq. 4, C_d column at alpha), eta_N(N), pumping constant
    a_clip = min(max(alpha, 0.0), prm.alpha_max_rad)
    area = math.pi * prm.r_th_m * prm.r_th_m * (1.0 - math.cos(a_clip))
    xi0 = area * (1000.0 * p_a) / math.sqrt(r * t_a)
    a_deg = math.degrees(a_clip)
    cdv = [_interp_value(a_deg, prm.cd_alpha_deg, row) for row in prm.cd_table]
    cds = [(cdv[j + 1] - cdv[j]) / (prs[j + 1] - prs[j]) for j in range(nseg + 1)]
    prs0, prs_hi = prs[0], prs[-1]
    scale = _interp_value(n_rpm, prm.eta_n_rpm, prm.eta_n_val) / (r_c - 1.0)
    k_pump = n_rpm * prm.v_d_dm3 / (120.0 * v)
    krta = k * r * t_a
    kta = k * t_a
    kkp = k * k_pump
    km1kp = km1 * k_pump
    floor = P_FLOOR_KPA
    sqrt = math.sqrt

    # --- M ROS2 sub-steps; M is fixed on the first pass from the rates at the start
    p, t = p_im, t_im
    m = 0
    h = gh = 0.0
    i = 0
    while True:
        # stage 1 at (p, t): right-hand side and diagonal Jacobian (reference: manifold._rhs)
        pr = p / p_a
        if pr <= prc:
            psi, dpsi = psic, 0.0
        elif pr < pr_reg:
            root = sqrt(c * (1.0 - pr ** e2))
            pe1 = pr ** e1
            psi = pe1 * root
            dpsi = e1 * pr ** e1m1 * root - pe1 * c * e2 * pr ** e2m1 / (2.0 * root)
        else:
            s = 1.0 - pr
            if s < ms0:
                psi, dpsi = mpsi0, 0.0
            else:
                sa = abs(s)
                psi, dpsi = qa * s + qb * s * sa, -(qa + 2.0 * qb * sa)
        pc = prs0 if prs0 > pr else pr
        pc = prs_hi if prs_hi < pc else pc
        j = bisect_right(prs, pc) - 1
        j = nseg if nseg < j else j
        cd = cdv[j] + cds[j] * (pc - prs[j])
        dcd = cds[j] if prs0 < pr < prs_hi else 0.0
        mdot = xi0 * cd * psi
        dmdot = xi0 * (dcd * psi + cd * dpsi) / p_a
        pp = floor if floor > p else p
        resid = (p_exh / pp) ** e_eta
        deta = scale * e_eta * resid / pp if p > floor else 0.0
        eta = scale * (r_c - resid)
        q = h1 * (t_cool - t) + h2 * (t_a - t)
        pv = pp * v
        dp = krta * mdot / v - kkp * eta * p + km1 * q / v
        dtt = (r * t * mdot * (kta - t) + km1 * t * q) / pv - km1kp * eta * t
        jpp = krta * dmdot / v - kkp * (eta + p * deta)
        jtt = (r * mdot * (kta - 2.0 * t) + km1 * (q - hsum * t)) / pv - km1kp * eta
        if i == 0:
            m = max(dt * (abs(jpp) + abs(jtt)) / lam_max, dt * abs(dp) / dp_max,
                    dt * abs(dtt) / dt_max)
            m = min(max(math.ceil(m), 1), max_sub)
            h = dt / m
            gh = ROS2_GAMMA * h
        wp = 1.0 - gh * (0.0 if 0.0 < jpp else jpp)
        wt = 1.0 - gh * (0.0 if 0.0 < jtt else jtt)
        k1p = dp / wp
        k1t = dtt / wt
        # stage 2 at (p + h k1p, t + h k1t): rates only
        p2 = p + h * k1p
        p2 = floor if floor > p2 else p2
        t2 = t + h * k1t
        pr = p2 / p_a
        if pr <= prc:
            psi = psic
        elif pr < pr_reg:
            psi = pr ** e1 * sqrt(c * (1.0 - pr ** e2))
        else:
            s = 1.0 - pr
            psi = mpsi0 if s < ms0 else qa * s + qb * s * abs(s)
        pc = prs0 if prs0 > pr else pr
        pc = prs_hi if prs_hi < pc else pc
        j = bisect_right(prs, pc) - 1
        j = nseg if nseg < j else j
        mdot = xi0 * (cdv[j] + cds[j] * (pc - prs[j])) * psi
        pp = p2  # already >= floor (or NaN, as max() leaves it)
        eta = scale * (r_c - (p_exh / pp) ** e_eta)
        q = h1 * (t_cool - t2) + h2 * (t_a - t2)
        dp2 = krta * mdot / v - kkp * eta * p2 + km1 * q / v
        dt2 = (r * t2 * mdot * (kta - t2) + km1 * t2 * q) / (pp * v) - km1kp * eta * t2
        k2p = (dp2 - 2.0 * k1p) / wp
        k2t = (dt2 - 2.0 * k1t) / wt
        p += h * (1.5 * k1p + 0.5 * k2p)
        t += h * (1.5 * k1t + 0.5 * k2t)
        p = floor if floor > p else p
        i += 1
        if i >= m:
            return p, t, m
