"""Compiled loops of the throttle identification (vecu.kernels: numba with vecu[fast]); eq. (3)
is vecu.models.throttle.eq3_step."""

from __future__ import annotations

import math

from vecu.kernels import kernel
from vecu.models.throttle import clip_theta, eq3_step


@kernel
def one_step_predict(P, b1, b2, u, th, ci, out_th, out_i, out_rho):
    """Eq. (3) one step ahead from the measured angle th_k and current ci_k, rho simulated.

    P: 3x10 rows (a12, a21, a22, a23, a32, a33, b, c1, c2, c3) of modes 1-3, b1 / b2 the
    switching angles. rho is not measured: it runs on eq. (3) driven by the measured th and ci
    (a series-parallel predictor). Writes the predictions th_{k+1|k} (clipped to [0, 90]) and
    i_{k+1|k} for k + 1 = 1..n-1 (index 0 holds the measurement) and rho_k.
    """
    n = u.size
    r = 0.0
    out_th[0] = th[0]
    out_i[0] = ci[0]
    for k in range(n - 1):
        out_rho[k] = r
        tn, r, cn = eq3_step(P, b1, b2, th[k], r, ci[k], u[k])
        out_th[k + 1] = clip_theta(tn)
        out_i[k + 1] = cn
        if not math.isfinite(r) or abs(r) > 1e9:  # a trial parameter set that blows up
            r = 1e9 if r > 0.0 else -1e9
    out_rho[n - 1] = r


@kernel
def free_run(P, b1, b2, u, th0, i0, out_th, out_i):
    """Eq. (3) with w = 0 from (th0, rho = 0, i0): the paper's simulated trajectory (Fig. 2)."""
    n = u.size
    t = th0
    r = 0.0
    c = i0
    for k in range(n):
        out_th[k] = t
        out_i[k] = c
        tn, r, c = eq3_step(P, b1, b2, t, r, c, u[k])
        t = clip_theta(tn)
