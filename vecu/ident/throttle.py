"""Identify the throttle body of Vargas 2015 (eq. 3, Table I, F, H) from a trace (§III-B).

Data: u_k, the wattmeter y_k = i_k^2 + v_k and the angle theta_k (TPS). The current is seen only
through y (|i| ~ sqrt(y)); the velocity rho is not measured at all.

Method (docs/reproduction.md, "Identification"):
1. Start: the current calibration (Table I by default). Per mode, one-step least squares for the
   rows that are linear given rho: theta_{k+1} - theta_k = a12 rho_k and
   i_{k+1} = a32 rho_k + a33 i_k + b u_k, with rho_k from the start model's predictor.
2. Prediction-error fit (scipy.optimize.least_squares): eq. (3) one step ahead from the measured
   angle and current (rho run on the model, kernels.one_step_predict); residuals theta_{k+1} -
   theta_{k+1|k} and y_{k+1} - (i_{k+1|k}^2 + s_i^2), each scaled to unit variance.
   The paper's own criterion, the free-run (w = 0) simulation error over three blocks, is
   reported for the start and the fit, but not minimised: with the paper's per-step noise the
   free-run error is dominated by the noise, and its minimum lies far from the true parameters.
3. 95 % intervals from the Jacobian (s^2 (J^T J)^-1, residuals taken as white). A parameter
   whose interval is wider than its own size, or whose mode the trace hardly visits, is not
   identifiable from this trace: it keeps its start value and is reported as such. mode3.a12 is
   never fitted: rho is not measured, so its scale (and a12, a21, a23, c, a32 with it) is free;
   mode 3's a12 fixes it (the gauge). c2 in modes 2 and 3 multiplies sgn(theta - 1) = +1 only
   (c3 carries c2 + c3). The friction / offset terms c1..c3 are kept by default (DEFAULT_FIXED).
4. Switching angles: profile of the cost over a 0.5 deg grid around the start; kept at the
   start unless the best one lowers 2 x cost by more than 3.84 (chi-square, 1 dof).
5. Noise: F11 = std of the angle residual; F33 and H from the wattmeter residual,
   Var = 4 i^2 F33^2 + 2 F33^4 + H^2 regressed on i^2; F22 = 0 (eq. 3).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from vecu.ident.kernels import free_run, one_step_predict
from vecu.ident.trace import ThrottleData
from vecu.models.throttle import PAPER_THROTTLE, ModeParams, ThrottleModel

NAMES = ("a12", "a21", "a22", "a23", "a32", "a33", "b", "c1", "c2", "c3")
GAUGE = (2, 0)  # mode3.a12: the scale of the unmeasured rho
MIN_MODE_SAMPLES = 300  # a mode visited less than this is not identifiable from the trace
MIN_CURRENT_A = 1.0  # one-step LS of the current row: samples with |i| clearly above 0
CHI2_1DOF_95 = 3.84
BOUND_GRID_DEG = 0.5
BOUND_SPAN_DEG = 3.0
# The friction and offset terms trade off against a21 / a23 (theta and i move together in steady
# state): on simulated traces the cost is flat along that direction (within 0.3 %) while the
# estimator's error triples, so they keep their start values unless asked (--free)
DEFAULT_FIXED = ("c1", "c2", "c3")
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
    cost_start: float  # mean squared scaled one-step residual
    cost_fit: float
    free_run_mse_start: tuple[float, float]  # (theta deg^2, |i| A^2), the paper's criterion
    free_run_mse_fit: tuple[float, float]
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


class _Problem:
    """The prediction-error residuals for one trace; free parameters selected by a mask."""

    def __init__(self, data: ThrottleData, P0: np.ndarray, bounds: tuple[float, float],
                 var_i: float) -> None:
        self.u = np.ascontiguousarray(data.u, dtype=float)
        self.th = np.ascontiguousarray(data.theta, dtype=float)
        self.y = np.ascontiguousarray(data.y, dtype=float)
        self.ci = np.sqrt(np.maximum(self.y, 0.0))
        self.P0 = P0
        self.bounds = bounds
        self.var_i = var_i
        n = self.u.size
        self.p_th, self.p_i, self.rho = np.empty(n), np.empty(n), np.empty(n)
        self.s_th = self.s_y = 1.0

    def predict(self, P: np.ndarray, bounds: tuple[float, float] | None = None) -> None:
        b1, b2 = self.bounds if bounds is None else bounds
        one_step_predict(P, float(b1), float(b2), self.u, self.th, self.ci, self.p_th, self.p_i,
                         self.rho)

    def raw(self, P: np.ndarray, bounds: tuple[float, float] | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
        self.predict(P, bounds)
        r_th = self.th[1:] - self.p_th[1:]
        r_y = self.y[1:] - (self.p_i[1:] ** 2 + self.var_i)
        return r_th, r_y

    def scaled(self, P: np.ndarray, bounds: tuple[float, float] | None = None) -> np.ndarray:
        r_th, r_y = self.raw(P, bounds)
        return np.concatenate([r_th / self.s_th, r_y / self.s_y])

    def cost(self, P: np.ndarray, bounds: tuple[float, float] | None = None) -> float:
        r = self.scaled(P, bounds)
        return float(r @ r) / r.size


def _modes_of(theta: np.ndarray, bounds: tuple[float, float]) -> np.ndarray:
    return np.searchsorted(np.array(bounds, dtype=float), theta, side="left")


def _one_step_ls(prob: _Problem, P: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Per-mode least squares of the theta row (a12) and the current row (a32, a33, b) given
    the start model's rho; other entries unchanged."""
    P = P.copy()
    prob.predict(P)
    th, ci, u, rho = prob.th, prob.ci, prob.u, prob.rho
    mode = _modes_of(th[:-1], prob.bounds)
    dth = np.diff(th)
    inner = (th[:-1] > 0.5) & (th[:-1] < 89.5) & (th[1:] > 0.5) & (th[1:] < 89.5)
    for s in range(3):
        sel = (mode == s) & inner
        if free[s, 0] and sel.sum() > MIN_MODE_SAMPLES:
            r = rho[:-1][sel]
            if float(r @ r) > 0.0:
                P[s, 0] = float(r @ dth[sel]) / float(r @ r)
        cur = (mode == s) & (ci[:-1] > MIN_CURRENT_A) & (ci[1:] > MIN_CURRENT_A)
        if free[s, 4:7].all() and cur.sum() > MIN_MODE_SAMPLES:
            A = np.column_stack([rho[:-1][cur], ci[:-1][cur], u[:-1][cur]])
            sol, *_ = np.linalg.lstsq(A, ci[1:][cur], rcond=None)
            if np.all(np.isfinite(sol)) and 0.0 < sol[1] < 1.0 and sol[2] > 0.0:
                P[s, 4:7] = sol
    return P


def _fit(prob: _Problem, P: np.ndarray, free: np.ndarray, max_nfev: int
         ) -> tuple[np.ndarray, np.ndarray | None]:
    """least_squares over the free entries; returns (P, 95 % half-widths of the free ones)."""
    x0 = P[free]
    if x0.size == 0:
        return P, None

    def resid(x: np.ndarray) -> np.ndarray:
        Q = P.copy()
        Q[free] = x
        return prob.scaled(Q)

    scale = np.maximum(np.abs(x0), 1e-3)
    sol = least_squares(resid, x0, x_scale=scale, method="trf", max_nfev=max_nfev)
    Q = P.copy()
    Q[free] = sol.x
    J = sol.jac
    m, p = J.shape
    s2 = 2.0 * float(sol.cost) / max(m - p, 1)
    try:
        cov = np.linalg.pinv(J.T @ J) * s2
        half = CHI2_HALF * np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        half = np.full(p, np.inf)
    return Q, half


CHI2_HALF = 1.959964  # 95 % two-sided normal quantile


def _noise(prob: _Problem, P: np.ndarray) -> tuple[float, float, float]:
    """(F11, F33, H) per 1 ms step from the one-step residuals (module docstring, step 5)."""
    r_th, _ = prob.raw(P)
    inner = (prob.th[1:] > 0.5) & (prob.th[1:] < 89.5)
    f11 = float(np.std(r_th[inner])) if inner.any() else float(np.std(r_th))
    m2 = prob.p_i[1:] ** 2
    r = prob.y[1:] - m2
    r = r - r.mean()
    A = np.column_stack([4.0 * m2, np.ones_like(m2)])
    (var_w, c), *_ = np.linalg.lstsq(A, r * r, rcond=None)
    var_w = max(float(var_w), 1e-8)
    h2 = max(float(c) - 2.0 * var_w * var_w, 1e-4)
    return f11, math.sqrt(var_w), math.sqrt(h2)


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
                      fixed: tuple[str, ...] = DEFAULT_FIXED) -> ThrottleFit:
    """Fit eq. (3), the switching angles, F and H to the trace (module docstring); `fixed`
    names parameters ("mode3.c1", or "c1" for every mode) kept at their start values."""
    P0 = model_matrix(start)
    bounds = tuple(float(b) for b in start.mode_bounds_deg)
    prob = _Problem(data, P0, bounds, var_i=start.f_diag[2] ** 2)
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
    # scale the two residual kinds to unit variance at the start
    r_th, r_y = prob.raw(P0)
    prob.s_th, prob.s_y = max(float(np.std(r_th)), 1e-6), max(float(np.std(r_y)), 1e-6)
    cost_start = prob.cost(P0)
    P = _one_step_ls(prob, P0, free)
    if prob.cost(P) > cost_start:  # the LS start is worse than the calibration: drop it
        P = P0.copy()
    P, half = _fit(prob, P, free, max_nfev)
    # noise first estimate -> bias term s_i^2 of the wattmeter residual, then refit
    _, f33, _ = _noise(prob, P)
    prob.var_i = f33 * f33
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
    r_th, r_y = prob.raw(P)
    prob.s_th, prob.s_y = max(float(np.std(r_th)), 1e-6), max(float(np.std(r_y)), 1e-6)
    cost_start = prob.cost(P0)
    P, half = _fit(prob, P, free, max_nfev)
    bounds_status = "kept (no fit asked)"
    if fit_bounds:
        bounds, bounds_status = _profile_bounds(prob, P, bounds, counts)
        if bounds != prob.bounds:
            prob.bounds = bounds
            P, half = _fit(prob, P, free, max_nfev)
    f11, f33, h = _noise(prob, P)
    prob.var_i = f33 * f33
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
    fit = ThrottleFit(
        model=model, start=start, estimates=estimates, bounds_status=bounds_status,
        n_samples=data.n, mode_samples=tuple(int(c) for c in counts),  # type: ignore[arg-type]  # one count per mode (3), not a fixed-size literal
        cost_start=cost_start, cost_fit=prob.cost(P),
        free_run_mse_start=_mse(*_free_run_errors(data, start)),
        free_run_mse_fit=_mse(*_free_run_errors(data, model)))
    _residual_stats(fit, prob, P, data)
    return fit


def _mse(e_th: np.ndarray, e_i: np.ndarray) -> tuple[float, float]:
    return float(np.mean(e_th ** 2)), float(np.mean(e_i ** 2))


def _profile_bounds(prob: _Problem, P: np.ndarray, bounds: tuple[float, float],
                    counts: np.ndarray) -> tuple[tuple[float, float], str]:
    """Grid search of the two switching angles around the start (module docstring, step 4)."""
    if min(counts) < MIN_MODE_SAMPLES:
        return bounds, "not identifiable: a mode is hardly visited, switching angles kept"
    m = 2 * (prob.th.size - 1)
    base = prob.cost(P, bounds) * m
    steps = np.arange(-BOUND_SPAN_DEG, BOUND_SPAN_DEG + 1e-9, BOUND_GRID_DEG)
    best, best_b = base, bounds
    for d1 in steps:
        for d2 in steps:
            b = (bounds[0] + float(d1), bounds[1] + float(d2))
            if not 1.0 < b[0] < b[1] < 90.0:
                continue
            c = prob.cost(P, b) * m
            if c < best:
                best, best_b = c, b
    if base - best > CHI2_1DOF_95:
        return best_b, f"fitted on a {BOUND_GRID_DEG:g} deg grid (2 x cost -{base - best:.1f})"
    return bounds, "not identifiable from this trace: the cost is flat around the start, kept"


def _residual_stats(fit: ThrottleFit, prob: _Problem, P: np.ndarray, data: ThrottleData) -> None:
    r_th, _ = prob.raw(P)
    r_i = prob.ci[1:] - np.abs(prob.p_i[1:])
    mode = _modes_of(data.theta[:-1], prob.bounds)
    for s in range(3):
        sel = mode == s
        stats = {}
        for label, r in (("theta_deg", r_th), ("current_a", r_i)):
            v = r[sel]
            stats[label] = StateResiduals(float(v.mean()) if v.size else math.nan,
                                          float(v.std()) if v.size else math.nan, int(v.size))
        fit.residuals[f"mode{s + 1}"] = stats
    fit.theta_residual, fit.current_residual = r_th, r_i
    fit.free_run_theta_error, fit.free_run_current_error = _free_run_errors(data, fit.model)
