"""Filter-side throttle noise and prior (Vargas et al. 2015, Section III-C): Q = diag((alpha
F_ii)^2), R = HH^T = 1, x0 = 0, P0 = I; f is eq. (3) (vecu.models.throttle.eq3_step) with theta
clipped to [0, 90] deg as in the plant, h(x) = i^2 (eq. 4)."""

from __future__ import annotations

from vecu.estimators.common.covariance import DivergenceBounds
from vecu.models.throttle import F_DIAG, H_WATTMETER

X0: tuple[float, float, float] = (0.0, 0.0, 0.0)
# Divergence bounds for the throttle filters: |theta| <= 90 by construction, |i| and |rho| stay
# well below 1e3 in simulation; a trace of 1e6 (1000 deg std) is far beyond any honest estimate.
THROTTLE_BOUNDS = DivergenceBounds(max_trace=1e6, max_abs_state=1e6)


def process_noise_diag(noise_scale: float = 1.0,
                       f_diag: tuple[float, float, float] = F_DIAG) -> tuple[float, float, float]:
    """Diagonal of FF^T with F scaled by alpha (plant's noise_scale)."""
    a = float(noise_scale)
    return ((a * f_diag[0]) ** 2, (a * f_diag[1]) ** 2, (a * f_diag[2]) ** 2)


def measurement_noise_var(h_wattmeter: float = H_WATTMETER) -> float:
    """R = HH^T (1: standard Gaussian wattmeter noise)."""
    return h_wattmeter * h_wattmeter
