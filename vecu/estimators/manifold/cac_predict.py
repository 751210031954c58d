"""Cylinder-air-charge prediction HORIZON = 6 events ahead (Dutka 2006, Section IV, Table 1):
eq. 1 and eq. 5-6 run from x_n, CAC_pred(n) = eta P_im V_cyl / (R T_im) at x_n+6. Sources of x_n
(Table 1): "direct", "direct_ol" (`open_loop_temperatures`), "ekf", "sdkf"; known inputs:
docs/models.md, "Manifold estimators and CAC prediction".
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vecu.estimators.manifold.event import (
    F_ALPHA_MIN,
    F_NCYL,
    F_VCYL,
    coefficients,
    integrate_event,
    model_constants,
    sdc_matrix,
    signature_types,
)
from vecu.kernels import kernel
from vecu.models import manifold_integrator as mi
from vecu.models.manifold import air_charge_of, efficiency_of, event_map
from vecu.models.manifold_params import V8_5L7, EngineInput, ManifoldParams

HORIZON = 6


@dataclass(frozen=True)
class CacPredictionConfig:
    horizon: int = HORIZON
    known_setpoint: bool = True  # the setpoints of the horizon are known (delayed pedal)
    stride: int = 1  # predict at every stride-th event (the sums are scaled back by stride)


# id(params) -> (params, (model constants, kernel tables))
_ARGS: dict[int, tuple[ManifoldParams, tuple]] = {}


def _args(params: ManifoldParams, eta_scale: float = 1.0) -> tuple:
    """The prediction kernels' constants and tables for params (cached); eta_scale multiplies
    the eta_N table (the adaptive filter's c)."""
    hit = _ARGS.get(id(params))
    if hit is None or hit[0] is not params:
        hit = (params, (model_constants(params), *mi.tables(params)))
        _ARGS[id(params)] = hit
    args = hit[1]
    if eta_scale != 1.0:
        args = (*args[:-1], args[-1] * eta_scale)
    return args


def _prediction(x: np.ndarray, inputs: Sequence[EngineInput], params: ManifoldParams,
                eta_scale: float = 1.0) -> tuple[np.ndarray, float]:
    """(x after the inputs, CAC there at the last input's speed): predict_events. eta_scale
    multiplies the eta_N table (the adaptive filter's c). x: the first six states are used."""
    xa = np.ascontiguousarray(np.asarray(x, dtype=np.float64)[:6])
    rows = inputs[:1] if all(u is inputs[0] for u in inputs) else inputs  # held: one row
    ua = np.array([(u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool) for u in rows], dtype=np.float64)
    out = np.empty(6)
    cac = predict_events(xa, ua, len(inputs), out, *_args(params, eta_scale))
    return out, cac


def predict_state(x: np.ndarray, inputs: Sequence[EngineInput],
                  params: ManifoldParams = V8_5L7) -> np.ndarray:
    """x_n+len(inputs) from x_n through the noise-free event map of eq. 10 (models.manifold.f;
    predict_events)."""
    if not inputs:
        return np.array(np.asarray(x, dtype=float)[:6])
    return _prediction(x, inputs, params)[0]


def predict_cac(x: np.ndarray, inputs: Sequence[EngineInput],
                params: ManifoldParams = V8_5L7, eta_scale: float = 1.0) -> float:
    """Predicted CAC (kg per cylinder event) after the inputs, at the last input's speed;
    eta_scale multiplies the calibrated eta (the adaptive filter's correction)."""
    return _prediction(x, inputs, params, eta_scale)[1]


def prediction_errors(states: np.ndarray, ta_sp: np.ndarray, n_rpm: np.ndarray,
                      cac_actual: np.ndarray, params: ManifoldParams = V8_5L7,
                      config: CacPredictionConfig = CacPredictionConfig(),
                      eta_scale: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, CAC_pred(n), CAC_actual(n + horizon)) in kg for n = 0, stride, ... (predict_at_events);
    eta_scale: per event, the adaptive filter's c (None: 1)."""
    hz = config.horizon
    idx = np.arange(0, len(cac_actual) - hz, max(1, config.stride))
    pred = np.empty(len(idx))
    scale = np.ones(len(states)) if eta_scale is None else np.asarray(eta_scale, dtype=float)
    if hz >= 1 and len(idx):
        u_amb = np.array([params.p_a_kpa, params.t_a_k, params.t_cool_k])
        predict_at_events(np.ascontiguousarray(states[:, :6], dtype=np.float64), idx,
                          np.ascontiguousarray(ta_sp, dtype=np.float64),
                          np.ascontiguousarray(n_rpm, dtype=np.float64), hz,
                          config.known_setpoint, u_amb, np.ascontiguousarray(scale), pred,
                          *_args(params))
    return idx, pred, cac_actual[idx + hz]


def open_loop_temperatures(ta_meas: np.ndarray, n_rpm: np.ndarray, p0: float, t0: float,
                           params: ManifoldParams = V8_5L7,
                           inputs: Sequence[EngineInput] | None = None) -> np.ndarray:
    """T_im,n of the open-loop observer: eq. 5-6 from (p0, t0) driven by the measured TA_n (the
    last finite one) at N_n, no feedback; ambient from inputs (None: nominal); open_loop_run."""
    n_ev = len(ta_meas)
    out = np.empty(n_ev)
    if inputs is None:
        amb = np.tile([params.p_a_kpa, params.t_a_k, params.t_cool_k], (n_ev, 1))
    else:
        amb = np.array([(u.p_a, u.t_a, u.t_cool) for u in inputs], dtype=np.float64)
    amb = np.ascontiguousarray(amb, dtype=np.float64).reshape(n_ev, 3)
    open_loop_run(np.ascontiguousarray(ta_meas, dtype=np.float64),
                  np.ascontiguousarray(n_rpm, dtype=np.float64), float(p0), float(t0), amb,
                  float(params.n_cyl), *mi.tables(params), out)
    return out


@kernel
def predict_events(x, u, count, out, fc, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """x after `count` events through the event map (cac_predict.predict_state) into out;
    returns the CAC (kg) there at the last input's speed (predict_cac). u: rows (TA_SP, N, P_a,
    T_a, T_cool); event i uses row min(i, len(u) - 1) (one row: input held)."""
    u_prev, alpha, alpha_prev = float(x[0]), float(x[1]), float(x[2])  # plain floats in Python
    p, t, tm = float(x[3]), float(x[4]), float(x[5])
    ts_prev = math.nan
    co = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    n_rpm = 0.0
    last = u.shape[0] - 1
    for i in range(count):
        r = min(last, i)
        sp, n_rpm, p_a = float(u[r, 0]), float(u[r, 1]), float(u[r, 2])
        t_a, t_cool = float(u[r, 3]), float(u[r, 4])
        ts = 120.0 / (fc[F_NCYL] * n_rpm)
        if ts != ts_prev:
            co = coefficients(ts, fc)
            ts_prev = ts
        p_n, t_n, _ = integrate_event(p, t, alpha, p_a, t_a, t_cool, n_rpm, ts, c, cd_alpha,
                                      cd_table, prs, eta_rpm, eta_val)
        alpha_n, tm_n = event_map(co, u_prev, alpha, alpha_prev, sp, t, tm)
        u_prev, alpha, alpha_prev, p, t, tm = sp, alpha_n, alpha, p_n, t_n, tm_n
    out[0], out[1], out[2], out[3], out[4], out[5] = u_prev, alpha, alpha_prev, p, t, tm
    return air_charge_of(n_rpm, p, t, c, fc[F_VCYL], eta_rpm, eta_val)


@kernel
def open_loop_run(ta_meas, n_rpm, p0, t0, amb, ncyl, c, cd_alpha, cd_table, prs, eta_rpm,
                  eta_val, out):
    """The open-loop observer over the events (open_loop_temperatures): out[n] = T_im,n; amb[n]
    the event's (P_a, T_a, T_coolant)."""
    p, t = p0, t0
    alpha = math.nan
    for n in range(len(ta_meas)):
        out[n] = t
        a = ta_meas[n] if math.isfinite(ta_meas[n]) else alpha
        if not math.isfinite(a):
            continue
        alpha = a
        ts = 120.0 / (ncyl * n_rpm[n])
        p, t, _ = integrate_event(p, t, a, amb[n][0], amb[n][1], amb[n][2], n_rpm[n], ts, c,
                                  cd_alpha, cd_table, prs, eta_rpm, eta_val)


@kernel
def predict_at_events(states, idx, ta_sp, n_rpm, horizon, known_setpoint, u_amb, eta_scale,
                      pred, fc, c, cd_alpha, cd_table, prs, eta_rpm, eta_val):
    """cac_predict.prediction_errors' predictions: pred[j] = CAC_pred(idx[j]) (kg) from
    states[idx[j]] over the horizon (the known setpoints, or the one held; N held), the
    eta_N table scaled by eta_scale[idx[j]] (1: the calibration as it is)."""
    last = len(ta_sp) - 1
    u = np.empty((horizon, 5))
    out = np.empty(6)
    for j in range(len(idx)):
        n = idx[j]
        for k in range(horizon):
            m = min(last, n + k)
            u[k, 0] = ta_sp[m] if known_setpoint else ta_sp[n]
            u[k, 1] = n_rpm[n]
            u[k, 2], u[k, 3], u[k, 4] = u_amb[0], u_amb[1], u_amb[2]
        ev = eta_val if eta_scale[n] == 1.0 else eta_val * eta_scale[n]
        pred[j] = predict_events(states[n], u, horizon, out, fc, c, cd_alpha, cd_table, prs,
                                 eta_rpm, ev)


@kernel
def air_charge_gradient(n_rpm, p_im, t_im, c, v_cyl, eta_rpm, eta_val):
    """(dCAC/dP_im, dCAC/dT_im) of the cylinder air charge CAC = eta(N, P_im) P_im V_cyl /
    (R_air T_im) (eq. 8 times T_s = 120 / (n_cyl N); models.manifold.air_charge_of):
    (eta + P_im d eta/dP_im) V_cyl / (R_air T_im) and -CAC / T_im, kg per kPa and per K."""
    eta, deta = efficiency_of(n_rpm, p_im, c, eta_rpm, eta_val)
    g_p = (eta + p_im * deta) * v_cyl / (c[1] * t_im)
    return g_p, -air_charge_of(n_rpm, p_im, t_im, c, v_cyl, eta_rpm, eta_val) / t_im


@kernel
def air_charge_sigmas(x, P, Q, horizon, n_rpm, p_a, t_a, t_cool, fc, c, cd_alpha, cd_table, prs,
                      eta_rpm, eta_val):
    """(sigma of the CAC at the posterior, `horizon` events ahead with u held), kg: g S g^T with
    g = air_charge_gradient and S the (P_im, T_im) block of P, then of S after `horizon` time
    updates of eq. 14 (S <- A S A^T + Q, A the SDC matrix at the posterior)."""
    ts = 120.0 / (fc[F_NCYL] * n_rpm)  # models.manifold.sample_time
    A = np.zeros((6, 6))
    sdc_matrix(A, x, n_rpm, p_a, t_a, t_cool, ts, coefficients(ts, fc), fc[F_ALPHA_MIN], c,
               cd_alpha, cd_table, prs, eta_rpm, eta_val)
    g_p, g_t = air_charge_gradient(n_rpm, x[3], x[4], c, fc[F_VCYL], eta_rpm, eta_val)
    S = np.empty((6, 6))
    Q6 = np.empty((6, 6))
    for i in range(6):
        for j in range(6):
            S[i, j] = P[i, j]
            Q6[i, j] = Q[i, j]
    var = g_p * g_p * S[3, 3] + 2.0 * g_p * g_t * S[3, 4] + g_t * g_t * S[4, 4]
    now = math.sqrt(var) if var > 0.0 else 0.0
    for _ in range(horizon):
        S = A @ S @ A.T + Q6
    var = g_p * g_p * S[3, 3] + 2.0 * g_p * g_t * S[3, 4] + g_t * g_t * S[4, 4]
    return now, math.sqrt(var) if var > 0.0 else 0.0


def cac_sigmas(x: np.ndarray, P: np.ndarray, Q: np.ndarray, u: EngineInput,
               params: ManifoldParams, horizon: int = HORIZON, eta_scale: float = 1.0
               ) -> tuple[float, float]:
    """air_charge_sigmas for a filter's posterior (x, P; its Q) and the event's input u;
    eta_scale multiplies the eta_N table (the adaptive filter's c)."""
    return air_charge_sigmas(x, P, Q, horizon, u.n_rpm, u.p_a, u.t_a, u.t_cool,
                             *_args(params, eta_scale))


def _predict_signature() -> tuple:
    _, f8, i8, v, m, tables = signature_types()
    return (v, m, i8, v, v) + tables


def _sigmas_signature() -> tuple:
    _, f8, i8, v, m, tables = signature_types()
    return (v, m, m, i8, f8, f8, f8, f8, v) + tables


predict_events.fix_signature(_predict_signature)
air_charge_sigmas.fix_signature(_sigmas_signature)
