"""The manifold model's scalar pieces as compiled kernels (vecu.kernels): the values of
vecu.models.manifold's `_interp`, `volumetric_efficiency` and `throttle_flow`, written on the
event integrator's constants `c` (manifold_integrator._param_consts, a tuple or float64 array)
and its tables, in the same floating-point operations and order (bit-identical: compiled code
calls them inside whole-event and whole-run loops, the plant's `simulate_events`, the filters'
event kernels, the air-charge prediction)."""

# ruff: noqa: FURB136 (x if c else y mirrors Python's min()/max(), NaN included)
from __future__ import annotations

import math
from bisect import bisect_right

from vecu.kernels import kernel
from vecu.models import manifold_integrator as mi


@kernel
def interp_value(x, xs, ys):
    """vecu.models.manifold._interp's value (same operations; xs, ys 1-d)."""
    last = len(xs) - 1
    if x <= xs[0]:
        return ys[0]
    if x >= xs[last]:
        return ys[len(ys) - 1]
    i = bisect_right(xs, x) - 1
    s = (ys[i + 1] - ys[i]) / (xs[i + 1] - xs[i])
    return ys[i] + s * (x - xs[i])


@kernel
def eta_value(n_rpm, p_im, c, eta_rpm, eta_val):
    """volumetric_efficiency(n_rpm, p_im)[0], c the integrator's constants."""
    eta_n = interp_value(n_rpm, eta_rpm, eta_val)
    floor = mi.P_FLOOR_KPA
    p = floor if floor > p_im else p_im
    resid = (c[20] / p) ** c[21]
    scale = eta_n / (c[19] - 1.0)
    return scale * (c[19] - resid)


@kernel
def throttle_flow_value(alpha, p_im, p_a, t_a, c, cd_alpha, cd_table, prs):
    """throttle_flow(alpha, p_im, p_a, t_a)[0] (flow_function, discharge_coefficient,
    throttle_area as written in vecu.models.manifold)."""
    pr = p_im / p_a
    if pr <= c[4]:
        psi = c[5]
    elif pr < c[11]:
        psi = pr ** c[7] * math.sqrt(c[6] * (1.0 - pr ** c[8]))
    else:
        s = 1.0 - pr
        psi = c[13] if s < c[12] else c[14] * s + c[15] * s * abs(s)
    a = 0.0 if 0.0 > alpha else alpha
    a = c[26] if c[26] < a else a
    a_deg = math.degrees(a)
    n = len(prs)
    pc = prs[0] if prs[0] > pr else pr
    pc = prs[n - 1] if prs[n - 1] < pc else pc
    j = bisect_right(prs, pc) - 1
    j = n - 2 if n - 2 < j else j
    lo = interp_value(a_deg, cd_alpha, cd_table[j])
    hi = interp_value(a_deg, cd_alpha, cd_table[j + 1])
    cd = lo + (hi - lo) / (prs[j + 1] - prs[j]) * (pc - prs[j])
    area = math.pi * c[27] * c[27] * (1.0 - math.cos(a))
    xi0 = area * (1000.0 * p_a) / math.sqrt(c[1] * t_a)
    return xi0 * cd * psi


@kernel
def air_charge_value(n_rpm, p_im, t_im, c, v_cyl, eta_rpm, eta_val):
    """cylinder_air_charge (kg per cylinder event): eta P_im V_cyl / (R_air T_im)."""
    eta = eta_value(n_rpm, p_im, c, eta_rpm, eta_val)
    return eta * p_im * v_cyl / (c[1] * t_im)


@kernel
def port_flow_value(n_rpm, p_im, t_im, c, eta_rpm, eta_val):
    """port_flow, eq. 8 (kg/s): eta P_im N V_d / (120 R_air T_im)."""
    eta = eta_value(n_rpm, p_im, c, eta_rpm, eta_val)
    return eta * p_im * n_rpm * c[28] / (120.0 * c[1] * t_im)
