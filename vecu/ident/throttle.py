"""Identify the throttle body of Vargas 2015 (eq. 3, Table I, F, H) from a trace (§III-B).

Data: u_k, the wattmeter y_k = i_k^2 + v_k and the angle theta_k (TPS). The current is seen only
through y (|i| ~ sqrt(y)); the velocity rho is not measured at all.

Method (docs/reproduction.md, "Identification"; the statistics in vecu.ident.prediction_error):
1. Start: the current calibration (Table I by default).
2. Prediction-error fit (scipy.optimize.least_squares) through an extended Kalman filter of
   eq. (3)-(4) with rho and i as states (kernels.innovations): the residuals are the filter's
   innovations of the angle and the wattmeter, weighted by 1 / sqrt(S) frozen at the previous
   estimate; the wattmeter is used only where the predicted current is clear of 0 (i^2 has no
   sign). Alternated with the noise (F11, F33, H) by maximum likelihood. Feeding the noisy
   |i| ~ sqrt(y) into eq. (3) as if it were the state (the former one-step fit) is an
   errors-in-variables regression: biased. The paper's own criterion, the free-run (w = 0)
   simulation error over three blocks, is reported for the start and the fit, but not
   minimised: with the paper's per-step noise the free-run error is dominated by the noise, and
   its minimum lies far from the true parameters.
3. 95 % intervals: sandwich covariance with a Newey-West (HAC) long-run covariance of the
   per-sample scores, valid for correlated residuals. A parameter whose interval is wider than
   its own size, or whose mode the trace hardly visits, is not identifiable from this trace: it
   keeps its start value and is reported as such. mode3.a12 is never fitted: rho is not
   measured, so its scale (and a12, a21, a23, c, a32 with it) is free; mode 3's a12 fixes it (the
   gauge). c2 in modes 2 and 3 multiplies sgn(theta - 1) = +1 only (c3 carries c2 + c3). The
   friction / offset terms c1..c3 are kept by default (DEFAULT_FIXED).
4. Switching angles: profile of the cost over a 0.5 deg grid around the start; kept at the
   start unless the best one lowers the cost (2 x negative log-likelihood) by more than 3.84
   (chi-square, 1 dof).
5. Noise: F11, F33 and H are the filter's, by maximum likelihood; F22 = 0 (eq. 3); the TPS noise
   is the sensor's (TPS_NOISE_DEG).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from vecu.ident.kernels import E_TH, I_PRED, free_run
from vecu.ident.prediction_error import (
    Problem,
    hac_window,
    half_widths,
    noise_ml,
    sandwich,
)
from vecu.ident.trace import ThrottleData
from vecu.models.throttle import PAPER_THROTTLE, ModeParams, ThrottleModel

NAMES = ("a12", "a21", "a22", "a23", "a32", "a33", "b", "c1", "c2", "c3")
GAUGE = (2, 0)  # mode3.a12: the scale of the unmeasured rho
MIN_MODE_SAMPLES = 300  # a mode visited less than this is not identifiable from the trace
FIRST_ROUNDS = 2  # noise ML / weights / prediction-error fit, alternated (the 2nd moves little)
# the TPS electrical noise (1 sigma): vecu's sensor, 0.002 V on 0.5-4.5 V for 0-90 deg; small
# against F11 (0.59 deg), so the fit hardly depends on it
TPS_NOISE_DEG = 0.045
CHI2_1DOF_95 = 3.84
BOUND_GRID_DEG = 0.5
BOUND_SPAN_DEG = 3.0
# The friction and offset terms trade off against a21 / a23 (theta and i move together in steady
# state): on simulated traces the cost is flat along that direction (within 0.3 %) while the
# estimator's error triples, so they keep their start values unless asked (--free)
DEFAULT_FIXED = ("c1", "c2", "c3")
METHOD = "prediction error through an extended Kalman filter (rho and i as states)"
INTERVAL = "sandwich, Newey-West HAC"
FREE_RUN_BLOCKS = 3  # the paper's three blocks
FREE_RUN_BLOCK = 10_000  # of 10 000 points each


@dataclass(frozen=True)
class Estimate:
    """One parameter: value, 95 % half-width (None if not fitted), start value, status."""

    name: str
    value: float
    ci95: float | None
    start: float
    status: str  # "fitted" or why it was not


@dataclass(frozen=True)
class StateResiduals:
    mean: float
    std: float
    n: int


@dataclass
class ThrottleFit:
    """Result of identify_throttle (see the module docstring)."""

    model: ThrottleModel
    start: ThrottleModel
    estimates: list[Estimate]
    bounds_status: str
    n_samples: int
    mode_samples: tuple[int, int, int]
    cost_start: float  # mean squared weighted innovation, fitted noise (1 for a model that fits)
    cost_fit: float
    free_run_mse_start: tuple[float, float]  # (theta deg^2, |i| A^2), the paper's criterion
    free_run_mse_fit: tuple[float, float]
    tps_noise_deg: float = TPS_NOISE_DEG
    hac_window: int = 0  # the Bartlett window of the intervals (samples)
    method: str = METHOD
    interval: str = INTERVAL
    residuals: dict[str, dict[str, StateResiduals]] = field(default_factory=dict)
    theta_residual: np.ndarray = field(default_factory=lambda: np.zeros(0))
    current_residual: np.ndarray = field(default_factory=lambda: np.zeros(0))
    free_run_theta_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    free_run_current_error: np.ndarray = field(default_factory=lambda: np.zeros(0))


def model_matrix(model: ThrottleModel) -> np.ndarray:
    """3x10: the modes' eq. (3) parameters in NAMES order."""
    return np.array([[getattr(p, n) for n in NAMES] for p in model.modes], dtype=float)


def with_matrix(model: ThrottleModel, P: np.ndarray, bounds: tuple[float, float] | None = None,
                f_diag: tuple[float, float, float] | None = None,
                h: float | None = None) -> ThrottleModel:
    modes = [ModeParams(**{n: float(P[s, j]) for j, n in enumerate(NAMES)}) for s in range(3)]
    return dataclasses.replace(
        model, mode1=modes[0], mode2=modes[1], mode3=modes[2],
        mode_bounds_deg=model.mode_bounds_deg if bounds is None else bounds,
        f_diag=model.f_diag if f_diag is None else f_diag,
        h_wattmeter=model.h_wattmeter if h is None else h)


def _modes_of(theta: np.ndarray, bounds: tuple[float, float]) -> np.ndarray:
    return np.searchsorted(np.array(bounds, dtype=float), theta, side="left")


def _fit(prob: Problem, P: np.ndarray, free: np.ndarray, max_nfev: int
         ) -> tuple[np.ndarray, np.ndarray | None]:
    """Weighted prediction-error least squares over the free entries (weights frozen at the
    start of the call); returns (P, 95 % half-widths of the free ones, HAC sandwich)."""
    x0 = P[free]
    if x0.size == 0:
        return P, None

    def resid(x: np.ndarray) -> np.ndarray:
        Q = P.copy()
        Q[free] = x
        return prob.residuals(Q)

    scale = np.maximum(np.abs(x0), 1e-3)
    # ftol / xtol 1e-6: the cost is ~1e5 (a sum of squared unit innovations), so the last steps
    # move it by < 0.1, far below one parameter's chi-square scale
    sol = least_squares(resid, x0, x_scale=scale, method="trf", max_nfev=max_nfev,
                        ftol=1e-6, xtol=1e-6)
    Q = P.copy()
    Q[free] = sol.x
    try:
        half = half_widths(sandwich(sol.jac, sol.fun))
    except np.linalg.LinAlgError:
        half = np.full(x0.size, np.inf)
    return Q, half


def _refit(prob: Problem, P: np.ndarray, free: np.ndarray, max_nfev: int, rounds: int
           ) -> tuple[np.ndarray, np.ndarray | None]:
    """Alternate: noise by ML, weights frozen, eq. (3) by prediction error (rounds times)."""
    half = None
    for _ in range(rounds):
        noise_ml(prob, P)
        prob.freeze(P)
        P, half = _fit(prob, P, free, max_nfev)
    return P, half


def _free_run_errors(data: ThrottleData, model: ThrottleModel) -> tuple[np.ndarray, np.ndarray]:
    """theta_sim - theta and |i_sim| - sqrt(y) over up to three blocks of 10 000 points, each
    simulated with w = 0 from the block's first measured angle and current (paper, §III-B)."""
    P = model_matrix(model)
    b1, b2 = model.mode_bounds_deg
    n = data.n
    block = min(FREE_RUN_BLOCK, n // FREE_RUN_BLOCKS)
    ci = np.sqrt(np.maximum(data.y, 0.0))
    e_th, e_i = [], []
    for j in range(FREE_RUN_BLOCKS):
        sl = slice(j * block, (j + 1) * block)
        u = np.ascontiguousarray(data.u[sl], dtype=float)
        o_th, o_i = np.empty(u.size), np.empty(u.size)
        free_run(P, float(b1), float(b2), u, float(data.theta[sl][0]), float(ci[sl][0]), o_th, o_i)
        e_th.append(o_th - data.theta[sl])
        e_i.append(np.abs(o_i) - ci[sl])
    return np.concatenate(e_th), np.concatenate(e_i)


def identify_throttle(data: ThrottleData, start: ThrottleModel = PAPER_THROTTLE,
                      max_nfev: int = 60, fit_bounds: bool = True,
                      fixed: tuple[str, ...] = DEFAULT_FIXED,
                      tps_noise_deg: float = TPS_NOISE_DEG) -> ThrottleFit:
    """Fit eq. (3), the switching angles, F and H to the trace (module docstring); `fixed`
    names parameters ("mode3.c1", or "c1" for every mode) kept at their start values."""
    P0 = model_matrix(start)
    bounds = tuple(float(b) for b in start.mode_bounds_deg)
    f = start.f_diag
    prob = Problem(data, bounds,  # type: ignore[arg-type]  # two switching angles
                   (f[0], f[2], start.h_wattmeter, tps_noise_deg))
    counts = np.bincount(_modes_of(data.theta, bounds), minlength=3)[:3]
    free = np.ones((3, 10), dtype=bool)
    why = np.full((3, 10), "", dtype=object)
    free[GAUGE] = False
    why[GAUGE] = "fixed: gauge (rho is not measured; mode 3's a12 sets its scale)"
    for s in range(3):
        if counts[s] < MIN_MODE_SAMPLES:
            free[s] = False
            why[s] = f"not identifiable: mode {s + 1} has only {counts[s]} samples"
    for s in (1, 2):  # theta > 1 throughout modes 2 and 3: sgn(theta - 1) = +1, c2 + c3 only
        free[s, 8] = False
        why[s, 8] = "not identifiable: sgn(theta - 1) = +1 throughout the mode (c3 holds c2 + c3)"
        P0[s, 9] += P0[s, 8]
        P0[s, 8] = 0.0
    for s in range(3):
        for j, name in enumerate(NAMES):
            if free[s, j] and (name in fixed or f"mode{s + 1}.{name}" in fixed):
                free[s, j] = False
                why[s, j] = ("kept: trades off against a21 / a23 (flat cost), --free to fit"
                             if name in DEFAULT_FIXED else "kept (--fix)")
    free[GAUGE] = False
    P, half = _refit(prob, P0.copy(), free, max_nfev, FIRST_ROUNDS)
    # parameters the trace cannot pin down go back to their start values
    if half is not None:
        vals = P[free]
        loose = half > np.maximum(np.abs(vals), 1e-4)
        idx = np.argwhere(free)
        for (s, j), bad, hw in zip(idx, loose, half):
            if bad:
                free[s, j] = False
                P[s, j] = P0[s, j]
                why[s, j] = f"not identifiable: 95 % interval +-{hw:.3g} wider than the value"
        if loose.any():
            P, half = _refit(prob, P, free, max_nfev, 1)
    bounds_status = "kept (no fit asked)"
    if fit_bounds:
        bounds, bounds_status = _profile_bounds(prob, P, bounds, counts)
        if bounds != prob.bounds:
            prob.bounds = bounds
            P, half = _refit(prob, P, free, max_nfev, 1)
    f11, f33, h = (float(v) for v in prob.noise[:3])
    model = with_matrix(start, P, bounds, (f11, 0.0, f33), h)
    estimates = []
    k = 0
    for s in range(3):
        for j, name in enumerate(NAMES):
            ci95 = None
            if free[s, j]:
                ci95 = float(half[k]) if half is not None else None
                k += 1
            estimates.append(Estimate(f"mode{s + 1}.{name}", float(P[s, j]), ci95,
                                      float(P0[s, j]), "fitted" if free[s, j] else str(why[s, j])))
    prob.freeze(P0)  # both costs under the fitted noise
    cost_start = prob.cost(P0) / prob.scored()
    prob.freeze(P)
    fit = ThrottleFit(
        model=model, start=start, estimates=estimates, bounds_status=bounds_status,
        n_samples=data.n, mode_samples=tuple(int(c) for c in counts),  # type: ignore[arg-type]  # one count per mode (3), not a fixed-size literal
        cost_start=cost_start, cost_fit=prob.cost(P) / prob.scored(),
        free_run_mse_start=_mse(*_free_run_errors(data, start)),
        free_run_mse_fit=_mse(*_free_run_errors(data, model)),
        tps_noise_deg=tps_noise_deg, hac_window=hac_window(data.n))
    _residual_stats(fit, prob, P, data)
    return fit


def _mse(e_th: np.ndarray, e_i: np.ndarray) -> tuple[float, float]:
    return float(np.mean(e_th ** 2)), float(np.mean(e_i ** 2))


def _profile_bounds(prob: Problem, P: np.ndarray, bounds: tuple[float, float],
                    counts: np.ndarray) -> tuple[tuple[float, float], str]:
    """Grid search of the two switching angles around the start (module docstring, step 4)."""
    if min(counts) < MIN_MODE_SAMPLES:
        return bounds, "not identifiable: a mode is hardly visited, switching angles kept"
    base = prob.cost(P, bounds)
    steps = np.arange(-BOUND_SPAN_DEG, BOUND_SPAN_DEG + 1e-9, BOUND_GRID_DEG)
    best, best_b = base, bounds
    for d1 in steps:
        for d2 in steps:
            b = (bounds[0] + float(d1), bounds[1] + float(d2))
            if not 1.0 < b[0] < b[1] < 90.0:
                continue
            c = prob.cost(P, b)
            if c < best:
                best, best_b = c, b
    if base - best > CHI2_1DOF_95:
        return best_b, f"fitted on a {BOUND_GRID_DEG:g} deg grid (2 x cost -{base - best:.1f})"
    return bounds, "not identifiable from this trace: the cost is flat around the start, kept"


def _residual_stats(fit: ThrottleFit, prob: Problem, P: np.ndarray, data: ThrottleData) -> None:
    out = prob.run(P)
    sel = prob.scored_y & (prob.gate[:, 1] > 0.5)
    r_th = out[:, E_TH][sel]
    r_i = np.sqrt(np.maximum(prob.y, 0.0))[sel] - np.abs(out[:, I_PRED][sel])
    mode = _modes_of(data.theta[sel], prob.bounds)
    for s in range(3):
        in_mode = mode == s
        stats = {}
        for label, r in (("theta_deg", r_th), ("current_a", r_i)):
            v = r[in_mode]
            stats[label] = StateResiduals(float(v.mean()) if v.size else math.nan,
                                          float(v.std()) if v.size else math.nan, int(v.size))
        fit.residuals[f"mode{s + 1}"] = stats
    fit.theta_residual, fit.current_residual = r_th, r_i
    fit.free_run_theta_error, fit.free_run_current_error = _free_run_errors(data, fit.model)
