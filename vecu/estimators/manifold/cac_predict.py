"""Cylinder-air-charge (CAC) prediction 6 events ahead (Dutka 2006, Section IV, Table 1).

The feedforward fuel controller needs the air charge of the cylinder whose fuel it injects now,
HORIZON events later. At event n it takes a state x_n (measured or estimated), runs the model
(actuator eq. 1 for the future throttle trajectory, manifold eq. 5-6, the plant's sub-stepped
event map) over the next HORIZON events and returns
    CAC_pred(n) = eta P_im V_cyl / (R T_im) at x_n+6 (kg per cylinder event),
to be compared with the simulated CAC_actual(n + 6).

What the controller knows at event n (decisions, docs/models.md "Manifold estimators"):
- the throttle setpoints TA_SP,n..n+5 (known_setpoint=True, default): a drive-by-wire ECU delays
  the pedal command by the prediction horizon, which is why a throttle model can predict the
  throttle trajectory at all (the paper's ref. [1]); known_setpoint=False holds TA_SP,n;
- the engine speed N_n only, held over the horizon (event period and eta_N from N_n);
- nominal P_a, T_a, T_coolant.

Four sources of x_n (the paper's Table 1 columns):
- "direct": the readings: alpha = TA_n, alpha_prev = TA_n-1, u_prev = TA_SP,n-1, P_im = P_n,
  T_im = T_im.meas = T_im.out,n (the slow IAT sensor, tau 8 s);
- "direct_ol": the same, but T_im from an open-loop observer: the manifold model (P, T) run
  without feedback, driven by the measured throttle angle (`OpenLoopTemperature`);
- "ekf", "sdkf": the filter posteriors x_n|n (vecu/estimators/manifold_filters.py).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from vecu.estimators.manifold.block_kernels import (
    open_loop_temperatures as open_loop_temperatures_kernel,
)
from vecu.estimators.manifold.block_kernels import predict_at_events
from vecu.estimators.manifold.kernels import (
    model_constants,
    numba_tables,
    predict_events,
)
from vecu.estimators.manifold.kernels import prepare as prepare_kernels
from vecu.models.manifold import (
    actuator_coeffs,
    cylinder_air_charge,
    iat_coeffs,
    integrate_manifold,
    sample_time,
)
from vecu.models.manifold_params import V8_5L7, EngineInput, ManifoldParams

HORIZON = 6
_PREDICT_EVENTS_PY = predict_events.py
METHODS = ("direct", "direct_ol", "ekf", "sdkf")


@dataclass(frozen=True)
class CacPredictionConfig:
    horizon: int = HORIZON
    known_setpoint: bool = True  # the setpoints of the horizon are known (delayed pedal)
    stride: int = 1  # predict at every stride-th event (the sums are scaled back by stride)


def horizon_inputs(ta_sp: Sequence[float], n: int, n_rpm: float, params: ManifoldParams = V8_5L7,
                   config: CacPredictionConfig = CacPredictionConfig()) -> list[EngineInput]:
    """EngineInputs for events n..n+horizon-1: known (or held) setpoints, N_n held."""
    last = len(ta_sp) - 1
    out = []
    for k in range(config.horizon):
        sp = ta_sp[min(n + k, last)] if config.known_setpoint else ta_sp[n]
        out.append(EngineInput(float(sp), n_rpm, params.p_a_kpa, params.t_a_k, params.t_cool_k))
    return out


# id(params) -> (params, kernel constants and tables or None)
_KERNEL_ARGS: dict[int, tuple[ManifoldParams, tuple | None]] = {}


def _compiled_prediction(x: np.ndarray, inputs: Sequence[EngineInput], params: ManifoldParams,
                         eta_scale: float = 1.0) -> tuple[np.ndarray, float] | None:
    """(x after the inputs, CAC there) by the kernel manifold_kernels.predict_events (numba),
    or None when the Python path runs (python backend, no inputs, odd x or parameter set).
    eta_scale != 1 (the adaptive filter's c: the eta_N table scaled) always runs the kernel,
    its Python function under the python backend. x: the first six states are used."""
    run = predict_events.impl()
    if (run is _PREDICT_EVENTS_PY and eta_scale == 1.0) or not inputs:
        return None
    hit = _KERNEL_ARGS.get(id(params))
    if hit is None or hit[0] is not params:
        tables = numba_tables(params)
        hit = (params, None if tables is None else (model_constants(params), *tables))
        _KERNEL_ARGS[id(params)] = hit
    args = hit[1]
    xa = np.ascontiguousarray(np.asarray(x, dtype=np.float64)[:6])
    if args is None or xa.shape != (6,):
        return None
    if eta_scale != 1.0:
        args = (*args[:-1], args[-1] * eta_scale)
    if run is not _PREDICT_EVENTS_PY:
        prepare_kernels()
    u0 = inputs[0]
    held = True
    for u in inputs:
        if u is not u0:
            held = False
            break
    rows = inputs[:1] if held else inputs
    ua = np.array([(u.ta_sp, u.n_rpm, u.p_a, u.t_a, u.t_cool) for u in rows], dtype=np.float64)
    out = np.empty(6)
    cac = run(xa, ua, len(inputs), out, *args)
    return out, cac


def predict_state(x: np.ndarray, inputs: Sequence[EngineInput],
                  params: ManifoldParams = V8_5L7) -> np.ndarray:
    """x_n+len(inputs) from x_n through the noise-free event map (manifold_model.f, written out
    on plain floats with the event coefficients computed once per event period: same result).
    Under the numba backend one kernel call (bit-identical)."""
    fast = _compiled_prediction(x, inputs, params)
    if fast is not None:
        return fast[0]
    vals = [float(v) for v in np.asarray(x, dtype=float)[:6]]
    ts_prev = math.nan
    for u in inputs:
        ts = sample_time(u.n_rpm, params.n_cyl)
        if ts != ts_prev:
            a1, a2, b1, b2 = actuator_coeffs(ts, params)
            a_t, b_t = iat_coeffs(ts, params)
            ts_prev = ts
        u_prev, alpha, alpha_prev, p, t, tm = vals
        p_n, t_n, _ = integrate_manifold(p, t, alpha, u, ts, params)
        sp = u.ta_sp
        vals = [sp, a1 * alpha + a2 * alpha_prev + b1 * sp + b2 * u_prev, alpha, p_n, t_n,
                a_t * tm + b_t * t]
    return np.array(vals)


def predict_cac(x: np.ndarray, inputs: Sequence[EngineInput],
                params: ManifoldParams = V8_5L7, eta_scale: float = 1.0) -> float:
    """Predicted CAC (kg per cylinder event) after the inputs, at the last input's speed;
    eta_scale multiplies the calibrated eta (the adaptive filter's correction)."""
    fast = _compiled_prediction(x, inputs, params, eta_scale)
    if fast is not None:
        return fast[1]
    xe = predict_state(x, inputs, params)
    return cylinder_air_charge(float(xe[3]), float(xe[4]), inputs[-1].n_rpm, params)


def direct_state(y: Sequence[float], y_prev: Sequence[float], sp_prev: float) -> np.ndarray:
    """x_n from the readings alone: (TA_SP,n-1, TA_n, TA_n-1, P_n, T_out,n, T_out,n)."""
    return np.array([sp_prev, y[0], y_prev[0], y[1], y[2], y[2]], dtype=float)


class OpenLoopTemperature:
    """Open-loop manifold observer: (P, T) of eq. 5-6 driven by the measured throttle angle, no
    feedback. step(TA_n, u_n) returns T_im,n and advances to n+1. Starts at the given state."""

    def __init__(self, p0: float, t0: float, params: ManifoldParams = V8_5L7) -> None:
        self.params = params
        self.p = float(p0)
        self.t = float(t0)
        self._alpha = math.nan

    def step(self, ta_meas: float, u: EngineInput) -> float:
        t_now = self.t
        a = ta_meas if math.isfinite(ta_meas) else self._alpha
        if not math.isfinite(a):
            return t_now
        self._alpha = a
        ts = sample_time(u.n_rpm, self.params.n_cyl)
        self.p, self.t, _ = integrate_manifold(self.p, self.t, a, u, ts, self.params)
        return t_now


def prediction_errors(states: np.ndarray, ta_sp: np.ndarray, n_rpm: np.ndarray,
                      cac_actual: np.ndarray, params: ManifoldParams = V8_5L7,
                      config: CacPredictionConfig = CacPredictionConfig(),
                      compiled: bool = True, eta_scale: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For events n = 0, stride, 2 stride, ... with n + horizon in range:
    (n, CAC_pred(n), CAC_actual(n + horizon)), CAC in kg. Under the numba backend (compiled)
    all predictions in one call (block_kernels.predict_at_events: the same numbers). eta_scale:
    per event, the eta correction the state came with (the adaptive filter's c; None: 1)."""
    hz = config.horizon
    idx = np.arange(0, len(cac_actual) - hz, max(1, config.stride))
    pred = np.empty(len(idx))
    scale = np.ones(len(states)) if eta_scale is None else np.asarray(eta_scale, dtype=float)
    if compiled and _predict_block(states, idx, ta_sp, n_rpm, params, config, pred, scale):
        return idx, pred, cac_actual[idx + hz]
    sp = ta_sp.tolist()
    for j, n in enumerate(idx):
        inputs = horizon_inputs(sp, int(n), float(n_rpm[n]), params, config)
        pred[j] = predict_cac(states[n], inputs, params, float(scale[n]))
    return idx, pred, cac_actual[idx + hz]


def _predict_block(states: np.ndarray, idx: np.ndarray, ta_sp: np.ndarray, n_rpm: np.ndarray,
                   params: ManifoldParams, config: CacPredictionConfig, pred: np.ndarray,
                   eta_scale: np.ndarray) -> bool:
    """prediction_errors' predictions into pred by one compiled call; False: not available."""
    if predict_events.impl() is _PREDICT_EVENTS_PY or config.horizon < 1 or not len(idx):
        return False
    tables = numba_tables(params)
    if tables is None:
        return False
    prepare_kernels()
    u_amb = np.array([params.p_a_kpa, params.t_a_k, params.t_cool_k])
    predict_at_events.compiled(np.ascontiguousarray(states[:, :6], dtype=np.float64), idx,
                               np.ascontiguousarray(ta_sp, dtype=np.float64),
                               np.ascontiguousarray(n_rpm, dtype=np.float64), config.horizon,
                               config.known_setpoint, u_amb, np.ascontiguousarray(eta_scale),
                               pred, model_constants(params), *tables)
    return True


def open_loop_temperatures(ta_meas: np.ndarray, n_rpm: np.ndarray, p0: float, t0: float,
                           params: ManifoldParams = V8_5L7) -> np.ndarray:
    """T_im,n of OpenLoopTemperature(p0, t0) stepped with (TA_n, nominal input at N_n) over the
    events; under the numba backend one compiled call (block_kernels.open_loop_temperatures)."""
    from vecu.models import manifold_integrator as mi

    n_ev = len(ta_meas)
    out = np.empty(n_ev)
    tables = mi._tables(params)[2]
    if predict_events.impl() is not _PREDICT_EVENTS_PY and tables is not None:
        prepare_kernels()
        u_amb = np.array([params.p_a_kpa, params.t_a_k, params.t_cool_k])
        open_loop_temperatures_kernel.compiled(
            np.ascontiguousarray(ta_meas, dtype=np.float64),
            np.ascontiguousarray(n_rpm, dtype=np.float64), float(p0), float(t0), u_amb,
            float(params.n_cyl), *tables, out)
        return out
    ol = OpenLoopTemperature(p0, t0, params)
    for n in range(n_ev):
        out[n] = ol.step(float(ta_meas[n]), EngineInput(0.0, float(n_rpm[n]), params.p_a_kpa,
                                                         params.t_a_k, params.t_cool_k))
    return out
