"""The throttle body simulator's ticks ahead as one compiled kernel (numba backend).

`advance_ticks` is ThrottlePlant's wattmeter(), tps_voltage() and step() (Vargas 2015 eq. 3-4
with vecu's TPS law) for consecutive 1 ms ticks, in the same floating-point operations and order,
over the plant's noise rows (one row per tick). vecu.plant.node.ThrottlePart uses it under numba
(the plant depends on nothing the ECU sends); tests/plant/test_node.py holds it to stepping.
"""

# ruff: noqa: FURB136 (x if c else y mirrors clip_theta, NaN included)
from __future__ import annotations

from vecu.kernels import kernel

# advance_ticks' constants vector
(K_SIG_THETA, K_SIG_I, K_H, K_TPS_NOISE, K_V0, K_V90, K_BOUND1, K_BOUND2) = range(8)
# a mode's row of Table I in `modes`
(M_A12, M_A21, M_A22, M_A23, M_A32, M_A33, M_B, M_C1, M_C2, M_C3) = range(10)


@kernel
def _sgn(v):
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


@kernel
def advance_ticks(st, u, noise, pos, modes, cst, out):
    """Ticks k = 0.. of u: out[k] = (theta_k, y_k = i_k^2 + H v_k (eq. 4), the TPS voltage) on
    x_k, then x_{k+1} = f(x_k, u_k) + F w_k (eq. 3), theta clipped to [0, 90] deg; st = (theta,
    rho, i) is advanced in place, noise rows taken from pos on. Stops when u, out or the noise
    rows run out; returns (ticks, the next noise row)."""
    theta, rho, i = st[0], st[1], st[2]
    k = 0
    while k < len(u) and k < len(out) and pos < len(noise):
        w = noise[pos]
        out[k, 0] = theta
        out[k, 1] = i * i + cst[K_H] * w[2]
        out[k, 2] = cst[K_V0] + (cst[K_V90] - cst[K_V0]) * theta / 90.0 + cst[K_TPS_NOISE] * w[3]
        m = 0 if theta <= cst[K_BOUND1] else (1 if theta <= cst[K_BOUND2] else 2)
        p = modes[m]
        theta_n = theta + p[M_A12] * rho
        rho_n = (p[M_A21] * theta + p[M_A22] * rho + p[M_A23] * i
                 + p[M_C1] * _sgn(rho) + p[M_C2] * _sgn(theta - 1.0) + p[M_C3])
        i_n = p[M_A32] * rho + p[M_A33] * i + p[M_B] * u[k]
        th = theta_n + cst[K_SIG_THETA] * w[0]
        theta = 0.0 if th < 0.0 else (90.0 if th > 90.0 else th)
        rho = rho_n
        i = i_n + cst[K_SIG_I] * w[1]
        pos += 1
        k += 1
    st[0], st[1], st[2] = theta, rho, i
    return k, pos
