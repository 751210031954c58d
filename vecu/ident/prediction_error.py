"""The prediction-error fit of the throttle identification: eq. (3)-(4) through a Kalman filter,
the noise by maximum likelihood, and intervals valid for correlated residuals.

Why a filter: rho is not measured and the current is seen only through y = i^2 + v (eq. 4), so
any predictor that feeds the noisy |i| ~ sqrt(y) (or a rho run on it) into eq. (3) as if it were
the state regresses on a noisy regressor: an errors-in-variables fit, biased (on a 60 s trace with
mode3.b = 0.0508 the former one-step fit gave 0.0544 +- 0.0019). The filter's innovations are the
measurements minus their conditional means given the past, so at the true parameters they are
uncorrelated with anything the past determines (the predictor's parameter gradients included):
the weighted sum of squared innovations has zero-mean gradient there and its minimiser is
consistent (Ljung's prediction-error method).

- `Problem.residuals`: innovations (kernels.innovations) scaled by weights 1 / sqrt(S_k) frozen
  from the filter at the last estimate (`Problem.freeze`): a fixed weighting keeps the estimating
  equation unbiased (letting S vary with the parameters would reward parameters that inflate S).
- `noise_ml`: (F11, F33, H) maximising the Gaussian likelihood of the innovations, eq. (3)
  parameters given; the TPS noise is the sensor's (small against F11: the angle is all but
  measured).
- `sandwich`: covariance A^-1 B A^-1 of the estimating equation, A = J^T J, B the Newey-West (HAC,
  Bartlett kernel, 0.5 s) long-run covariance of the per-sample scores: valid when the scores
  are correlated (the filter is an approximation: the signs, i^2, the stops), equal to
  s^2 (J^T J)^-1 when they are white.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize

from vecu.ident.kernels import E_TH, E_Y, S_TH, S_Y, innovations
from vecu.ident.trace import ThrottleData

BURN_IN = 50  # samples: the filter's start from (theta_0, rho = 0, sqrt(y_0)) settling
Z95 = 1.959964  # two-sided 95 % normal quantile
# HAC bandwidth (samples): the residuals' correlation lasts as long as the filter's errors, the
# slowest being rho's in mode 2 (a22 = 0.994: 170 ms); 0.5 s is three of those
HAC_WINDOW = 500
# the wattmeter is used where the predicted current is this many of its sigmas from 0
# (kernels.innovations): 2 keeps the filter's update near the conditional mean (the other
# branch holds 2 %) while using about half of the samples (3: 40 %, and b's spread 2.7 % -> 2.4 %)
GATE_SIGMAS = 2.0


class Problem:
    """The weighted innovations of one trace: residual vector [theta part, wattmeter part],
    each of length n (zero where not scored), so that sample k's two entries are k and n + k."""

    def __init__(self, data: ThrottleData, bounds: tuple[float, float],
                 noise: tuple[float, float, float, float]) -> None:
        self.u = np.ascontiguousarray(data.u, dtype=float)
        self.th = np.ascontiguousarray(data.theta, dtype=float)
        self.y = np.ascontiguousarray(data.y, dtype=float)
        self.bounds = bounds
        self.noise = np.array(noise, dtype=float)  # F11, F33, H, TPS noise (deg)
        n = self.u.size
        self.out = np.empty((n, 5))
        scored = np.ones(n, dtype=bool)
        scored[:BURN_IN] = False
        self.scored_y = scored.copy()
        self.scored_th = scored.copy()  # and not at a stop (the filter's S = inf there)
        self.w_th = np.zeros(n)
        self.w_y = np.zeros(n)
        self.gate = np.ones((n, 2))  # (angle scored, wattmeter used), frozen by freeze()

    @property
    def n(self) -> int:
        return int(self.u.size)

    def run(self, P: np.ndarray, bounds: tuple[float, float] | None = None,
            noise: np.ndarray | None = None, decide: bool = False) -> np.ndarray:
        """The filter's (e_theta, S_theta, e_y, S_y, i_{k|k-1}) rows (a view, valid until the
        next run); the wattmeter gate frozen, or decided anew (and kept) with `decide`."""
        b1, b2 = self.bounds if bounds is None else bounds
        q = self.noise if noise is None else noise
        g2 = GATE_SIGMAS ** 2 if decide else 0.0
        innovations(P, float(b1), float(b2), self.u, self.th, self.y, q, self.gate, g2, self.out)
        return self.out

    def freeze(self, P: np.ndarray) -> None:
        """The wattmeter gate and the weights 1 / sqrt(S_k) from the filter at P (and the
        current noise)."""
        out = self.run(P, decide=True)
        self.w_th = np.where(self.scored_th, 1.0 / np.sqrt(out[:, S_TH]), 0.0)
        self.w_y = np.where(self.scored_y, 1.0 / np.sqrt(out[:, S_Y]), 0.0)

    def residuals(self, P: np.ndarray, bounds: tuple[float, float] | None = None) -> np.ndarray:
        out = self.run(P, bounds)
        r = np.concatenate([out[:, E_TH] * self.w_th, out[:, E_Y] * self.w_y])
        return np.where(np.isfinite(r), r, 1e3)

    def cost(self, P: np.ndarray, bounds: tuple[float, float] | None = None) -> float:
        """Sum of squared weighted innovations (2 x the negative log-likelihood up to terms
        that do not depend on the parameters, at the weights' parameters)."""
        r = self.residuals(P, bounds)
        return float(r @ r)

    def scored(self) -> int:
        """How many residuals count (angle and wattmeter samples)."""
        return int(np.count_nonzero(self.w_th) + np.count_nonzero(self.w_y))

    def neg_log_likelihood(self, P: np.ndarray, noise: np.ndarray) -> float:
        """-log L of the scored innovations (Gaussian, up to a constant)."""
        out = self.run(P, noise=noise)
        total = 0.0
        for e, s, scored in ((E_TH, S_TH, self.scored_th), (E_Y, S_Y, self.scored_y)):
            sel = scored & np.isfinite(out[:, s])
            ee, ss = out[sel, e], out[sel, s]
            total += 0.5 * float(np.sum(ee * ee / ss + np.log(ss)))
        return total if math.isfinite(total) else 1e300


def noise_ml(prob: Problem, P: np.ndarray) -> None:
    """(F11, F33, H) by maximum likelihood with eq. (3)'s parameters P given (Nelder-Mead on
    their logarithms); the TPS noise stays. Sets prob.noise."""
    fixed_tps = float(prob.noise[3])

    def nll(x: np.ndarray) -> float:
        return prob.neg_log_likelihood(P, np.array([*np.exp(x), fixed_tps]))

    x0 = np.log(np.maximum(prob.noise[:3], 1e-3))
    sol = minimize(nll, x0, method="Nelder-Mead",
                   options={"xatol": 1e-3, "fatol": 0.05, "maxiter": 200})
    prob.noise = np.array([*np.exp(sol.x), fixed_tps])


def hac_window(n: int) -> int:
    """The Bartlett kernel's bandwidth: HAC_WINDOW samples, at most n / 20 (short traces)."""
    return max(1, min(HAC_WINDOW, n // 20))


def sandwich(J: np.ndarray, r: np.ndarray, window: int | None = None) -> np.ndarray:
    """Covariance of the least-squares estimate from the residuals r (length 2n: two per sample,
    see Problem) and their Jacobian J (2n x p): A^-1 B A^-1 with A = J^T J and B the long-run
    covariance of the per-sample scores psi_k = J_k^T r_k (both entries of sample k), Newey-West's
    Bartlett kernel computed as overlapping batch means: B = n / (L (n - L + 1)) sum_t W_t W_t^T,
    W_t the sum of psi over samples t .. t + L - 1."""
    n = r.size // 2
    psi = J[:n] * r[:n, None] + J[n:] * r[n:, None]
    L = hac_window(n) if window is None else window
    csum = np.vstack([np.zeros((1, psi.shape[1])), np.cumsum(psi, axis=0)])
    W = csum[L:] - csum[:-L]
    B = (W.T @ W) * (n / (L * (n - L + 1.0)))
    A_inv = np.linalg.pinv(J.T @ J)
    return A_inv @ B @ A_inv


def half_widths(cov: np.ndarray) -> np.ndarray:
    """95 % half-widths from a covariance matrix."""
    return Z95 * np.sqrt(np.maximum(np.diag(cov), 0.0))
