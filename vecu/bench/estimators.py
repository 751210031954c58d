"""Cost of one throttle UKF step: plain-float implementation vs the numpy reference, same run.

`python -m vecu.bench.estimators [steps]` prints one row per paper sigma set.
"""

from __future__ import annotations

import math
import sys
from typing import Any

from vecu.bench.reference_ukf import NumpyThrottleUKF
from vecu.clock import Stopwatch
from vecu.estimators.common.sigma_sets import PAPER_SETS
from vecu.estimators.throttle.ukf_fast import FastThrottleUKF
from vecu.models import manifold
from vecu.plant.throttle import simulate

BENCH_SEED = 1


def _us_per_step(est: FastThrottleUKF | NumpyThrottleUKF, u: list[float], y: list[float]) -> float:
    step = est.step
    n = len(y)
    watch = Stopwatch()
    for k in range(1, n):
        step(u[k - 1], y[k])
    return 1e6 * watch.elapsed() / (n - 1)


def bench_throttle_ukf(
    steps: int = 20_000, repeats: int = 5, noise_scale: float = 1.0
) -> list[dict[str, float | int | str]]:
    """us per step() for each paper set, fast and numpy, on one simulated trace.

    The fast filter runs `steps` steps, the numpy one steps // 10 steps (same trace prefix),
    alternately, `repeats` times each; each figure is the best (minimum) repeat, the one least
    disturbed by other load on the machine. ratio = numpy / fast.
    """
    if steps < 100 or repeats < 1:
        raise ValueError("need steps >= 100 and repeats >= 1")
    trace = simulate(steps, seed=BENCH_SEED, noise_scale=noise_scale)
    u = trace.u.tolist()
    y = trace.y.tolist()
    n_np = max(steps // 10, 100)
    rows: list[dict[str, float | int | str]] = []
    for name in PAPER_SETS:
        fast = ref = float("inf")
        for _ in range(repeats):
            fast = min(fast, _us_per_step(FastThrottleUKF(name, noise_scale), u, y))
            ref = min(ref, _us_per_step(NumpyThrottleUKF(name, noise_scale), u[:n_np], y[:n_np]))
        rows.append({
            "sigma_set": name,
            "points": FastThrottleUKF(name).sigma_set.points,
            "fast_us": fast,
            "numpy_us": ref,
            "ratio": ref / fast,
            "fast_steps": steps - 1,
            "numpy_steps": n_np - 1,
        })
    return rows


def format_rows(rows: list[dict[str, float | int | str]]) -> str:
    lines = [f"{'set':<6}{'points':>7}{'fast us':>10}{'numpy us':>10}{'ratio':>8}"]
    for r in rows:
        lines.append(f"{r['sigma_set']:<6}{r['points']:>7}{r['fast_us']:>10.2f}"
                     f"{r['numpy_us']:>10.1f}{r['ratio']:>8.1f}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    steps = int(args[0]) if args else 20_000
    print(f"throttle UKF, one step (predict + update), best of 5, seed {BENCH_SEED}")
    print(format_rows(bench_throttle_ukf(steps)))
    return 0


if __name__ == "__main__":
    sys.exit(main())


def _best_us(make, feed, steps: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        est = make()
        watch = Stopwatch()
        feed(est, steps)
        best = min(best, watch.elapsed() / steps * 1e6)
    return best


def bench_speed_and_steering(steps: int = 5_000, repeats: int = 3) -> list[dict[str, float | str]]:
    """us per step of the speed KF (budget 15 us at 500 Hz) and the steering UKF (budget 50 us),
    each against a same-run baseline: a straightforward numpy Kalman step for the speed filter,
    the (numpy-Jacobian) EKF for the steering UKF."""
    import numpy as np

    from vecu.estimators.speed.kf import SpeedKalmanFilter
    from vecu.estimators.steering.filters import SteeringEKF, SteeringUKF
    from vecu.plant.lateral import ManoeuvreConfig, simulate_lateral
    from vecu.plant.longitudinal import simulate_speed

    sp = simulate_speed(BENCH_SEED)
    w, acc = sp.wheel.tolist(), sp.accel.tolist()
    n_sp = min(steps, len(w))

    def feed_speed(f: SpeedKalmanFilter, n: int) -> None:
        for k in range(n):
            f.step(w[k], acc[k])

    dt = 0.002
    F = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    Q = np.diag([1e-6, 1e-3, 1e-8])
    H = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]])
    R = np.diag([0.1, 0.36])

    class NumpyKF:  # the textbook matrix form of the same 3-state filter
        def __init__(self) -> None:
            self.x = np.zeros(3)
            self.P = np.eye(3)

        def step(self, wheel: float, a: float) -> None:
            x = F @ self.x
            P = F @ self.P @ F.T + Q
            S = H @ P @ H.T + R
            K = P @ H.T @ np.linalg.inv(S)
            self.x = x + K @ (np.array([wheel, a]) - H @ x)
            self.P = (np.eye(3) - K @ H) @ P

    speed_us = _best_us(SpeedKalmanFilter, feed_speed, n_sp, repeats)
    numpy_us = _best_us(NumpyKF, feed_speed, n_sp, repeats)
    lat = simulate_lateral(BENCH_SEED, ManoeuvreConfig(duration_s=30.0))
    vx, r, ay = lat.meas_vx.tolist(), lat.meas_r.tolist(), lat.meas_ay.tolist()
    n_st = min(steps // 5, len(vx))

    def feed_steer(f: SteeringUKF | SteeringEKF, n: int) -> None:
        for k in range(n):
            f.step(vx[k], r[k], ay[k])

    ukf_us = _best_us(SteeringUKF, feed_steer, n_st, repeats)
    ekf_us = _best_us(SteeringEKF, feed_steer, n_st, repeats)
    return [
        {"filter": "speed KF (plain floats)", "us": speed_us, "baseline": "numpy matrix KF",
         "baseline_us": numpy_us, "ratio": numpy_us / speed_us, "budget_us": 15.0},
        {"filter": "steering UKF (plain floats)", "us": ukf_us, "baseline": "steering EKF (numpy)",
         "baseline_us": ekf_us, "ratio": ekf_us / ukf_us, "budget_us": 50.0},
    ]


def bench_manifold(duration_s: float = 80.0) -> list[dict[str, float | str]]:
    """us per engine event of the live SDKF (one warm-started Riccati iteration) and the EKF,
    against the SDKF that solves the DARE every event (doubling), on one simulated profile."""
    from vecu.eval.manifold import run_filter, trace_inputs
    from vecu.plant.drive_profile import DriveProfile, us06_like
    from vecu.plant.manifold import simulate

    prof = us06_like(BENCH_SEED)
    k = round(duration_s / prof.dt_s) + 1
    trace = simulate(DriveProfile(prof.dt_s, prof.n_rpm[:k], prof.ta_sp[:k]), seed=BENCH_SEED)
    inputs = trace_inputs(trace)
    n = len(trace.t)
    us = {name: 1e6 * run_filter(name, trace, inputs)[1] / n
          for name in ("sdkf", "ekf", "sdkf_doubling")}
    base = us["sdkf_doubling"]
    return [{"filter": name, "us_per_event": us[name], "baseline": "SDKF with a DARE per event",
             "baseline_us": base, "ratio": base / us[name], "budget_us": 200.0, "events": n}
            for name in ("sdkf", "ekf")]


# ------------------------------------------------------------------ straightforward baselines

class NumpyReferencePF:
    """Baseline for the production throttle estimator: a textbook numpy particle filter on the
    same model (eq. 3 per mode with boolean masks, theta noise and clip, the same linearised
    optimal proposal and predictive likelihood for i, systematic resampling by searchsorted when
    ESS < N/2), fresh arrays and random draws every step, a fixed 600 particles, no Kalman
    stretches. What the production filter's engineering is measured against (eq. 3 from
    vecu.models.throttle.mode_step, elementwise)."""

    def __init__(self, n: int = 600, noise_scale: float = 1.0, seed: int = 1) -> None:
        import numpy as np

        from vecu.models.throttle import F_DIAG

        self.np = np
        self.rng = np.random.default_rng(seed)
        self.n = n
        self.s_th = max(noise_scale * F_DIAG[0], 1e-3)
        self.s_i = max(noise_scale * F_DIAG[2], 1e-3)
        self.x = np.vstack([np.abs(self.rng.standard_normal(n)), self.rng.standard_normal(n),
                            self.rng.standard_normal(n)])
        self.w = np.full(n, 1.0 / n)
        self.theta_deg = 0.0

    def step(self, u: float, y: float | None) -> None:
        from vecu.models.throttle import MODE_BOUNDS_DEG, PAPER_THROTTLE, mode_step

        np, rng = self.np, self.rng
        th, rh, ci = self.x
        new = np.empty_like(self.x)
        modes = [th <= MODE_BOUNDS_DEG[0], (th > MODE_BOUNDS_DEG[0]) & (th <= MODE_BOUNDS_DEG[1]),
                 th > MODE_BOUNDS_DEG[1]]
        for p, m in zip(PAPER_THROTTLE.rows, modes):  # eq. (3) per mode, on arrays
            tm, rm = th[m], rh[m]
            new[0, m], new[1, m], new[2, m] = mode_step(p, tm, rm, ci[m], u, np.sign(rm),
                                                       np.sign(tm - 1.0))
        new[0] = np.clip(new[0] + self.s_th * rng.standard_normal(self.n), 0.0, 90.0)
        m = new[2]
        s2 = self.s_i ** 2
        if y is None:
            new[2] = m + self.s_i * rng.standard_normal(self.n)
        else:
            S = 1.0 + 4.0 * m * m * s2
            r = y - m * m - s2
            new[2] = m * (1.0 + 2.0 * s2 * r / S) + self.s_i * rng.standard_normal(self.n) / np.sqrt(S)
            self.w = self.w * np.exp(-0.5 * r * r / S) / np.sqrt(S)
            total = self.w.sum()
            if not total > 0.0:
                self.w = np.full(self.n, 1.0 / self.n)
            else:
                self.w = self.w / total
        self.x = new
        if 1.0 / np.sum(self.w * self.w) < 0.5 * self.n:
            cs = np.cumsum(self.w)
            pos = (rng.random() + np.arange(self.n)) / self.n
            idx = np.minimum(np.searchsorted(cs, pos), self.n - 1)
            self.x = self.x[:, idx]
            self.w = np.full(self.n, 1.0 / self.n)
        self.theta_deg = float(np.dot(self.w, self.x[0]))


def bench_throttle_production(steps: int = 20_000, repeats: int = 3,
                              noise_scale: float = 1.0) -> dict[str, float | str]:
    """us per step of the ECU's throttle estimator (production PF + Kalman stretches) against
    NumpyReferencePF on the same trace (steps // 4 steps of it), best of `repeats`."""
    from vecu.estimators.registry import make_throttle_estimator

    trace = simulate(steps, seed=BENCH_SEED, noise_scale=noise_scale)
    u, y = trace.u.tolist(), trace.y.tolist()

    def feed(est: Any, n: int) -> None:
        step = est.step
        for k in range(1, n):
            step(u[k - 1], y[k])

    prod = _best_us(lambda: make_throttle_estimator("production", noise_scale), feed, steps,
                    repeats)
    n_ref = max(steps // 4, 100)
    ref = _best_us(lambda: NumpyReferencePF(noise_scale=noise_scale), feed, n_ref, repeats)
    return {"filter": "throttle production PF/KF", "us": prod,
            "baseline": "textbook numpy PF, 600 particles", "baseline_us": ref,
            "ratio": ref / prod, "budget_us": 1000.0 / 20.0, "steps": steps}


# the plain continuous model of eq. 5-6: the baseline of the event integrator and the oracle of
# tests/estimators/manifold/test_fast_paths.py, tests/plant/test_manifold.py


def rhs_and_jacobian(p: float, t: float, alpha: float, u: Any,
                     prm: Any) -> tuple[float, float, float, float]:
    """(dP/dt, dT/dt, d(dP/dt)/dP, d(dT/dt)/dT) of the continuous model behind eq. 5-6, written
    plainly on the model's functions (vecu.models.manifold_integrator inlines it)."""
    k = prm.kappa
    r = prm.r_air
    v = prm.v_im_dm3
    mdot, dmdot = manifold.throttle_flow(alpha, p, u.p_a, u.t_a, prm)
    eta, deta = manifold.volumetric_efficiency(u.n_rpm, p, prm)
    k_pump = u.n_rpm * prm.v_d_dm3 / (120.0 * v)  # mdot_ac R T / (V_im eta P), 1/s
    q = manifold.heat_flow(t, u.t_a, u.t_cool, prm)
    pv = max(p, manifold.P_FLOOR_KPA) * v
    dp = k * r * u.t_a * mdot / v - k * k_pump * eta * p + (k - 1.0) * q / v
    dt = (r * t * mdot * (k * u.t_a - t) + (k - 1.0) * t * q) / pv - (k - 1.0) * k_pump * eta * t
    jpp = k * r * u.t_a * dmdot / v - k * k_pump * (eta + p * deta)
    hsum = prm.h1_w_per_k + prm.h2_w_per_k
    jtt = ((r * mdot * (k * u.t_a - 2.0 * t) + (k - 1.0) * (q - hsum * t)) / pv
           - (k - 1.0) * k_pump * eta)
    return dp, dt, jpp, jtt


def manifold_rhs(p_im: float, t_im: float, alpha: float, u: Any,
                 params: Any = manifold.V8_5L7) -> tuple[float, float]:
    """Continuous eq. 5-6: (dP_im/dt in kPa/s, dT_im/dt in K/s) at throttle angle alpha.

    dP/dt = kappa R (T_a mdot_at - T_im mdot_ac) / V_im + (kappa - 1) Q_ext / V_im
    dT/dt = T_im / (P_im V_im) [R mdot_at (kappa T_a - T_im) - (kappa - 1) R T_im mdot_ac
                                + (kappa - 1) Q_ext]
    One Euler step of length T_s = 120/(8N) gives eq. 5-6 with V_cyl = V_d/8 in the pumping terms.
    """
    dp, dt, _, _ = rhs_and_jacobian(p_im, t_im, alpha, u, params)
    return dp, dt


def euler_event(p_im: float, t_im: float, alpha: float, u: Any,
                params: Any = manifold.V8_5L7) -> tuple[float, float]:
    """Eq. 5-6 as printed (one explicit Euler step over T_s), with V_cyl = V_d/8. Unstable at large
    openings; for comparison only."""
    ts = manifold.sample_time(u.n_rpm, params.n_cyl)
    dp, dt, _, _ = rhs_and_jacobian(p_im, t_im, alpha, u, params)
    return p_im + ts * dp, t_im + ts * dt


def substeps(dp: float, dtt: float, jpp: float, jtt: float, dt: float, prm: Any) -> int:
    """Smallest M with h (|J_PP| + |J_TT|) <= lam_dt_max, |h dP/dt| <= dp_step_max and
    |h dT/dt| <= dt_step_max (h = dt/M), clamped to [1, max_substeps]."""
    m = max(
        dt * (abs(jpp) + abs(jtt)) / prm.lam_dt_max,
        dt * abs(dp) / prm.dp_step_max_kpa,
        dt * abs(dtt) / prm.dt_step_max_k,
    )
    return min(max(math.ceil(m), 1), prm.max_substeps)


def integrate_manifold_reference(p: float, t: float, alpha: float, u: Any, dt: float,
                                 prm: Any = None) -> tuple[float, float, int]:
    """vecu.models.manifold.integrate_manifold written plainly on the model's own functions
    (`_rhs` per stage: throttle_flow, volumetric_efficiency, heat_flow): the baseline of the
    hoisted, inlined implementation, and the oracle of tests/estimators/manifold/test_fast_paths.py."""
    prm = manifold.V8_5L7 if prm is None else prm
    g = manifold.ROS2_GAMMA
    dp, dtt, jpp, jtt = rhs_and_jacobian(p, t, alpha, u, prm)
    m = substeps(dp, dtt, jpp, jtt, dt, prm)
    h = dt / m
    for i in range(m):
        if i:
            dp, dtt, jpp, jtt = rhs_and_jacobian(p, t, alpha, u, prm)
        wp = 1.0 - g * h * min(jpp, 0.0)
        wt = 1.0 - g * h * min(jtt, 0.0)
        k1p, k1t = dp / wp, dtt / wt
        dp2, dt2, _, _ = rhs_and_jacobian(max(p + h * k1p, manifold.P_FLOOR_KPA), t + h * k1t,
                                          alpha, u, prm)
        k2p, k2t = (dp2 - 2.0 * k1p) / wp, (dt2 - 2.0 * k1t) / wt
        p += h * (1.5 * k1p + 0.5 * k2p)
        t += h * (1.5 * k1t + 0.5 * k2t)
        p = max(p, manifold.P_FLOOR_KPA)
    return p, t, m


def f_manifold_reference(x: Any, u: Any, ts: float, prm: Any = None) -> Any:
    """The event map of eq. 10 (vecu.models.manifold.f) through integrate_manifold_reference."""
    import numpy as np

    from vecu.models.manifold_params import V8_5L7

    prm = V8_5L7 if prm is None else prm
    u_prev, alpha, alpha_prev, p, t, tm = (float(v) for v in x)
    a1, a2, b1, b2, a_t, b_t = manifold.event_coefficients(ts, prm.zeta, prm.omega0,
                                                           prm.tau_temp_s)
    p_n, t_n, _ = integrate_manifold_reference(p, t, alpha, u, ts, prm)
    return np.array([u.ta_sp, a1 * alpha + a2 * alpha_prev + b1 * u.ta_sp + b2 * u_prev, alpha,
                     p_n, t_n, a_t * tm + b_t * t])


class PlainManifoldSDKF:
    """Baseline of the live SDKF, written straightforwardly: SDC matrices, one warm-started
    Riccati iteration, the gain by numpy (cholesky_lower + inv), the mean through
    f_manifold_reference; the state box, no gating or divergence guards."""

    def __init__(self) -> None:
        import numpy as np

        from vecu.estimators.manifold.filters import ManifoldFilterConfig
        from vecu.estimators.manifold.model import Y_INDEX, q_matrix, r_matrix

        self.np = np
        self.cfg = ManifoldFilterConfig()
        self.Q, self.R = q_matrix(self.cfg.noise), r_matrix(self.cfg.noise)
        self.C = np.zeros((3, 6))
        for i, j in enumerate(Y_INDEX):
            self.C[i, j] = 1.0
        self.x: Any = None
        self.P = np.diag(self.cfg.p0_diag)
        self.P_post = self.P

    def step(self, y: Any, u: Any) -> Any:
        """One event: update with y (all three channels), then predict; returns x_n|n."""
        from vecu.estimators.common.covariance import cholesky_lower, symmetrise
        from vecu.estimators.manifold.model import sdc_matrices

        np, c = self.np, self.cfg
        ts = manifold.sample_time(u.n_rpm, c.params.n_cyl)
        yv = np.array([float(v) for v in y])
        if self.x is None:
            self.x = np.array([yv[0], yv[0], yv[0], yv[1], yv[2], yv[2]])
        else:
            A, _ = sdc_matrices(self.x, u, c.params, ts)
            self.P = symmetrise(A @ self.P_post @ A.T + self.Q)
        PCt = self.P @ self.C.T
        L = cholesky_lower(self.C @ PCt + self.R)
        Linv = np.linalg.inv(L)
        K = PCt @ (Linv.T @ Linv)
        x = self.x + K @ (yv - self.C @ self.x)
        x[:3] = np.clip(x[:3], *c.alpha_box)
        x[3] = min(max(x[3], c.p_box[0]), c.p_box[1])
        x[4:] = np.clip(x[4:], *c.t_box)
        self.P_post = symmetrise(self.P - K @ PCt.T)
        self.x = f_manifold_reference(x, u, ts, c.params)
        return x


def bench_manifold_function(duration_s: float = 20.0) -> dict[str, float | str | int]:
    """us per engine event of what the ECU's manifold function computes (live SDKF step + the
    6-event CAC prediction) against the same two written plainly: PlainManifoldSDKF (reference
    integrator, numpy gain) and the prediction from x_n|n through f_manifold_reference six
    times. Same profile, same run."""
    from vecu.estimators.manifold.cac_predict import HORIZON, predict_cac
    from vecu.estimators.manifold.factory import make_filter
    from vecu.eval.manifold import trace_inputs
    from vecu.models.manifold import cylinder_air_charge
    from vecu.plant.drive_profile import DriveProfile, us06_like
    from vecu.plant.manifold import simulate

    prof = us06_like(BENCH_SEED)
    k = round(duration_s / prof.dt_s) + 1
    trace = simulate(DriveProfile(prof.dt_s, prof.n_rpm[:k], prof.ta_sp[:k]), seed=BENCH_SEED)
    inputs = trace_inputs(trace)
    ys = trace.y.tolist()

    def fast() -> float:
        flt = make_filter("sdkf")
        watch = Stopwatch()
        for y, u in zip(ys, inputs):
            flt.step(y, u)
            first = flt.last_prediction
            predict_cac(first[1], [u] * (HORIZON - 1))
        return watch.elapsed()

    def plain() -> float:
        flt = PlainManifoldSDKF()
        watch = Stopwatch()
        for y, u in zip(ys, inputs):
            x = flt.step(y, u)
            ts = manifold.sample_time(u.n_rpm)
            for _ in range(HORIZON):
                x = f_manifold_reference(x, u, ts)
            cylinder_air_charge(float(x[3]), float(x[4]), u.n_rpm)
        return watch.elapsed()

    n = len(ys)
    best_fast = min(fast() for _ in range(2))
    best_plain = min(plain() for _ in range(2))
    return {"filter": "manifold SDKF + 6-event CAC prediction", "us": best_fast / n * 1e6,
            "baseline": "same, straightforward (per-call model functions, numpy linalg update)",
            "baseline_us": best_plain / n * 1e6, "ratio": best_plain / best_fast,
            "budget_us": 200.0, "events": n}


def bench_steering_smoother(steps: int = 1_000, repeats: int = 3) -> dict[str, float | str]:
    """us per 10 ms step of the ECU's steering estimator (plain-float UKF inside the fixed-lag
    smoother) against the same smoother around the numpy EKF."""
    from vecu.estimators.steering.filters import SteeringEKF
    from vecu.estimators.steering.smoothers import FixedLagSmoother
    from vecu.plant.lateral import ManoeuvreConfig, simulate_lateral

    lat = simulate_lateral(BENCH_SEED, ManoeuvreConfig(duration_s=steps / 100.0 + 1.0))
    vx, r, ay = lat.meas_vx.tolist(), lat.meas_r.tolist(), lat.meas_ay.tolist()
    n = min(steps, len(vx))

    def feed(sm: FixedLagSmoother, n: int) -> None:
        for k in range(n):
            sm.step(vx[k], r[k], ay[k])

    ukf = _best_us(FixedLagSmoother, feed, n, repeats)
    ekf = _best_us(lambda: FixedLagSmoother(filt=SteeringEKF()), feed, n, repeats)
    return {"filter": "steering UKF + fixed-lag smoother", "us": ukf,
            "baseline": "same smoother around the numpy EKF", "baseline_us": ekf,
            "ratio": ekf / ukf, "budget_us": 500.0, "steps": n}
