"""The throttle body simulator's tick (Vargas 2015 eq. 3-4 with vecu's TPS law) as kernels.

`plant_step` is one 1 ms step of the stochastic eq. (3): ThrottlePlant.step calls it as plain
Python. `advance_ticks` runs consecutive ticks (measure, then step) over the plant's noise rows in
one compiled call: vecu.plant.node.ThrottlePart uses it under numba (the plant depends on nothing
the ECU sends); tests/plant/test_node.py holds it to stepping.
"""

from __future__ import annotations

from typing import Any

from vecu.kernels import kernel
from vecu.models.sensors import tps_law
from vecu.models.throttle import clip_theta, eq3_step, wattmeter_reading

# advance_ticks' constants vector
(K_SIG_THETA, K_SIG_I, K_H, K_TPS_NOISE, K_V0, K_V90, K_BOUND1, K_BOUND2) = range(8)


@kernel
def plant_step(rows: Any, b1: float, b2: float, sig_theta: float, sig_i: float, theta: float,
               rho: float, i: float, u: float, w_theta: float, w_i: float
               ) -> tuple[float, float, float]:
    """x_{k+1} = f(x_k, u_k) + F w_k (eq. 3, F = diag(sig_theta, 0, sig_i)), theta clipped to
    the stops [0, 90] deg after the noise."""
    theta_n, rho_n, i_n = eq3_step(rows, b1, b2, theta, rho, i, u)
    return clip_theta(theta_n + sig_theta * w_theta), rho_n, i_n + sig_i * w_i


@kernel
def advance_ticks(st, u, noise, pos, modes, cst, out):
    """Ticks k = 0.. of u: out[k] = (theta_k, y_k = i_k^2 + H v_k (eq. 4), the TPS voltage) on
    x_k, then plant_step; st = (theta, rho, i) is advanced in place, noise rows (w_theta, w_i,
    v, TPS noise) taken from pos on. modes: the 3x10 mode rows. Stops when u, out or the noise
    rows run out; returns (ticks, the next noise row)."""
    theta, rho, i = st[0], st[1], st[2]
    k = 0
    while k < len(u) and k < len(out) and pos < len(noise):
        w = noise[pos]
        out[k, 0] = theta
        out[k, 1] = wattmeter_reading(i, cst[K_H], w[2])
        out[k, 2] = tps_law(cst[K_V0], cst[K_V90], theta) + cst[K_TPS_NOISE] * w[3]
        theta, rho, i = plant_step(modes, cst[K_BOUND1], cst[K_BOUND2], cst[K_SIG_THETA],
                                   cst[K_SIG_I], theta, rho, i, u[k], w[0], w[1])
        pos += 1
        k += 1
    st[0], st[1], st[2] = theta, rho, i
    return k, pos
