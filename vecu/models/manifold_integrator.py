"""The event integrator of eq. 5-6 (vecu.models.manifold.integrate_manifold), written for speed:
one kernel (`_integrate_event`) on float64 tables (`tables`), the same operations and order as
the plain model (docs/models.md, "Corrections to the printed equations"). Bad input fails as
plain Python fails, never silently.
"""

# ruff: noqa: FURB136 (x if c else y mirrors min()/max() exactly, NaN included, without a call)
from __future__ import annotations

import math
from typing import Any

import numpy as np

from vecu.kernels import kernel
from vecu.models.manifold_params import V8_5L7, EngineInput, ManifoldParams

P_FLOOR_KPA = 0.5  # lower guard for P_im inside eta and the integrator (never reached in use)
ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)

# id(params) -> (params, its tables: tables())
_TABLES: dict[int, tuple[ManifoldParams, tuple]] = {}
N_CONSTS = 29  # len(_param_consts(...))


@kernel
def search_right(a: Any, x: float) -> int:
    """bisect.bisect_right(a, x): CPython's algorithm (the same index for any input, NaN too)."""
    lo = 0
    hi = len(a)
    while lo < hi:
        mid = (lo + hi) // 2
        if x < a[mid]:
            hi = mid
        else:
            lo = mid + 1
    return lo


@kernel
def interp(x: float, xs: Any, ys: Any) -> tuple[float, float]:
    """Piecewise-linear lookup with end clamping: (value, slope), slope 0 outside the table (the
    C_d and eta_N maps of eq. 2-3 and 8). A NaN x fails with IndexError under both backends."""
    last = len(xs) - 1
    if x <= xs[0]:
        return float(ys[0]), 0.0
    if x >= xs[last]:
        return float(ys[len(ys) - 1]), 0.0
    i = search_right(xs, x) - 1
    if i + 1 >= len(ys) or i + 1 > last:
        raise IndexError("table lookup out of range (NaN?)")
    y0, y1, x0 = float(ys[i]), float(ys[i + 1]), float(xs[i])  # plain floats in Python
    s = (y1 - y0) / (float(xs[i + 1]) - x0)
    return y0 + s * (x - x0), s


def _param_consts(prm: ManifoldParams) -> tuple[float, ...]:
    """Per-parameter-set constants, computed as the reference functions compute them."""
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
    return (
        k, prm.r_air, prm.v_im_dm3, k - 1.0,
        (2.0 / (k + 1.0)) ** (k / (k - 1.0)),  # critical pressure ratio
        math.sqrt(k) * (2.0 / (k + 1.0)) ** ((k + 1.0) / (2.0 * (k - 1.0))),  # psi choked
        c, e1, e2, e1 - 1.0, e2 - 1.0, pr_reg, -s0, -psi0, qa, qb,
        prm.h1_w_per_k, prm.h2_w_per_k, prm.h1_w_per_k + prm.h2_w_per_k,
        prm.r_c, prm.p_exh_kpa, 1.0 / prm.kappa,
        prm.lam_dt_max, prm.dp_step_max_kpa, prm.dt_step_max_k, float(prm.max_substeps),
        prm.alpha_max_rad, prm.r_th_m, prm.v_d_dm3,
    )


def tables(prm: ManifoldParams) -> tuple:
    """The integrator's arguments for a parameter set, cached: (constants tuple, C_d alpha, C_d
    table, C_d pr, eta_N rpm, eta_N values) as float64 arrays. ValueError for a set the kernels
    cannot take: a ragged C_d table, or kappa <= 1, pr_reg > 1 or p_exh < 0, where Python's
    sqrt and ** fail (negative roots, complex powers) and numba would return NaN."""
    hit = _TABLES.get(id(prm))
    if hit is not None and hit[0] is prm:
        return hit[1]
    if not (prm.kappa > 1.0 and prm.pr_reg <= 1.0 and prm.p_exh_kpa >= 0.0):
        raise ValueError("manifold parameters need kappa > 1, pr_reg <= 1 and p_exh >= 0 "
                         f"(kappa {prm.kappa:g}, pr_reg {prm.pr_reg:g}, p_exh {prm.p_exh_kpa:g})")
    try:
        arrays = tuple(np.array(t, dtype=np.float64) for t in (
            prm.cd_alpha_deg, prm.cd_table, prm.cd_pr, prm.eta_n_rpm, prm.eta_n_val))
    except ValueError:
        arrays = ()
    if len(arrays) != 5 or arrays[1].ndim != 2 or any(a.ndim != 1 for a in arrays[::2]) \
            or arrays[3].ndim != 1:
        raise ValueError("manifold parameters: the C_d table must be one row per cd_pr point "
                         "and one column per cd_alpha_deg point, the other tables flat")
    out = (tuple(float(x) for x in _param_consts(prm)), *arrays)
    _TABLES[id(prm)] = (prm, out)
    return out


def _signature() -> tuple:
    """_integrate_event's one signature: scalars float64, the tables float64 arrays."""
    from numba import types

    f8 = types.float64
    return (f8,) * 8 + (types.UniTuple(f8, N_CONSTS), f8[::1], f8[:, ::1], f8[::1], f8[::1],
                        f8[::1])


@kernel
def _integrate_event(p_im: float, t_im: float, alpha: float, p_a: float, t_a: float,
                     t_cool: float, n_rpm: float, dt: float, cst: Any, cd_alpha: Any,
                     cd_table: Any, prs: Any, eta_rpm: Any, eta_val: Any
                     ) -> tuple[float, float, int]:
    """One event of eq. 5-6 (see integrate_manifold); the tables as tuples or float64 arrays."""
    (k, r, v, km1, prc, psic, c, e1, e2, e1m1, e2m1, pr_reg, ms0, mpsi0, qa, qb,
     h1, h2, hsum, r_c, p_exh, e_eta, lam_max, dp_max, dt_max, max_sub_f,
     alpha_max, r_th, v_d) = cst
    max_sub = int(max_sub_f)
    nseg = len(prs) - 2
    # --- per event: throttle (eq. 4, C_d column at alpha), eta_N(N), pumping constant
    a_clip = 0.0 if 0.0 > alpha else alpha  # min(max(alpha, 0.0), alpha_max)
    a_clip = alpha_max if alpha_max < a_clip else a_clip
    area = math.pi * r_th * r_th * (1.0 - math.cos(a_clip))
    rta = r * t_a
    if rta < 0.0:  # as math.sqrt fails in Python (numba would return NaN)
        raise ValueError("math domain error")
    xi0 = area * (1000.0 * p_a) / math.sqrt(rta)
    a_deg = math.degrees(a_clip)
    nrow = len(cd_table)
    if nrow < nseg + 2:
        raise IndexError("C_d table has fewer rows than cd_pr breakpoints")
    cdv = [float(interp(a_deg, cd_alpha, cd_table[jr])[0]) for jr in range(nrow)]
    prl = [float(prs[j]) for j in range(nseg + 2)]  # plain floats in Python
    cds = [(cdv[j + 1] - cdv[j]) / (prl[j + 1] - prl[j]) for j in range(nseg + 1)]
    prs0, prs_hi = prl[0], prl[nseg + 1]
    eta_n = float(interp(n_rpm, eta_rpm, eta_val)[0])
    scale = eta_n / (r_c - 1.0)
    k_pump = n_rpm * v_d / (120.0 * v)
    krta = k * r * t_a
    kta = k * t_a
    kkp = k * k_pump
    km1kp = km1 * k_pump
    floor = P_FLOOR_KPA
    sqrt = math.sqrt

    # --- M ROS2 sub-steps; M is fixed on the first pass from the rates at the start. Each
    # sub-step evaluates the right-hand side twice: stage 1 at (p, t) with its diagonal
    # Jacobian, stage 2 at (p + h k1p, t + h k1t) rates only (first = True / False).
    p, t = p_im, t_im
    ps, tsv = p, t  # the stage's point
    first = True
    m = 0
    h = gh = wp = wt = k1p = k1t = 0.0
    i = 0
    while True:
        # eq. 2-4 and 5-6 at (ps, tsv) (reference: manifold._rhs)
        pr = ps / p_a
        dpsi = 0.0
        if pr <= prc:
            psi = psic
        elif pr < pr_reg:
            root = sqrt(c * (1.0 - pr ** e2))
            pe1 = pr ** e1
            psi = pe1 * root
            if first:
                dpsi = e1 * pr ** e1m1 * root - pe1 * c * e2 * pr ** e2m1 / (2.0 * root)
        else:
            s = 1.0 - pr
            if s < ms0:
                psi = mpsi0
            else:
                sa = abs(s)
                psi = qa * s + qb * s * sa
                if first:
                    dpsi = -(qa + 2.0 * qb * sa)
        pc = prs0 if prs0 > pr else pr
        pc = prs_hi if prs_hi < pc else pc
        j = search_right(prl, pc) - 1
        j = nseg if nseg < j else j
        cd = cdv[j] + cds[j] * (pc - prl[j])
        mdot = xi0 * cd * psi
        pp = floor if floor > ps else ps
        resid = (p_exh / pp) ** e_eta
        eta = scale * (r_c - resid)
        q = h1 * (t_cool - tsv) + h2 * (t_a - tsv)
        pv = pp * v
        dp = krta * mdot / v - kkp * eta * ps + km1 * q / v
        dtt = (r * tsv * mdot * (kta - tsv) + km1 * tsv * q) / pv - km1kp * eta * tsv
        if first:
            dcd = cds[j] if prs0 < pr < prs_hi else 0.0
            dmdot = xi0 * (dcd * psi + cd * dpsi) / p_a
            deta = scale * e_eta * resid / pp if ps > floor else 0.0
            jpp = krta * dmdot / v - kkp * (eta + ps * deta)
            jtt = (r * mdot * (kta - 2.0 * tsv) + km1 * (q - hsum * tsv)) / pv - km1kp * eta
            if i == 0:
                # m = min(max(ceil(max(a, b, c)), 1), max_sub) with max()'s and ceil's semantics
                mf = dt * (abs(jpp) + abs(jtt)) / lam_max
                mb = dt * abs(dp) / dp_max
                mf = mb if mb > mf else mf
                mb = dt * abs(dtt) / dt_max
                mf = mb if mb > mf else mf
                if math.isnan(mf):
                    raise ValueError("cannot convert float NaN to integer")
                if math.isinf(mf):
                    raise OverflowError("cannot convert float infinity to integer")
                if mf <= 1.0:
                    m = 1
                elif mf < max_sub:
                    m = math.ceil(mf)
                else:
                    m = max_sub
                m = max_sub if max_sub < m else m
                h = dt / m
                gh = ROS2_GAMMA * h
            wp = 1.0 - gh * (0.0 if 0.0 < jpp else jpp)
            wt = 1.0 - gh * (0.0 if 0.0 < jtt else jtt)
            k1p = dp / wp
            k1t = dtt / wt
            ps = p + h * k1p
            ps = floor if floor > ps else ps
            tsv = t + h * k1t
            first = False
        else:
            k2p = (dp - 2.0 * k1p) / wp
            k2t = (dtt - 2.0 * k1t) / wt
            p += h * (1.5 * k1p + 0.5 * k2p)
            t += h * (1.5 * k1t + 0.5 * k2t)
            p = floor if floor > p else p
            i += 1
            if i >= m:
                return p, t, m
            ps, tsv = p, t
            first = True


_integrate_event.fix_signature(_signature)


def integrate_manifold(p_im: float, t_im: float, alpha: float, u: EngineInput, dt: float,
                       params: ManifoldParams = V8_5L7) -> tuple[float, float, int]:
    """vecu.models.manifold.integrate_manifold: (P_im, T_im, M) by `_integrate_event`."""
    return _integrate_event(p_im, t_im, alpha, u.p_a, u.t_a, u.t_cool, u.n_rpm, dt,
                            *tables(params))
