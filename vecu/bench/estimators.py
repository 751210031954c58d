"""Cost of one throttle UKF step: plain-float implementation vs the numpy reference, same run.

`python -m vecu.bench.estimators [steps]` prints one row per paper sigma set.
"""

from __future__ import annotations

import sys
import time

from vecu.estimators.sigma_sets import PAPER_SETS
from vecu.estimators.throttle_model import NumpyThrottleUKF
from vecu.estimators.ukf_fast import FastThrottleUKF
from vecu.plant.throttle import simulate

BENCH_SEED = 1


def _us_per_step(est: FastThrottleUKF | NumpyThrottleUKF, u: list[float], y: list[float]) -> float:
    step = est.step
    n = len(y)
    t0 = time.perf_counter()
    for k in range(1, n):
        step(u[k - 1], y[k])
    return 1e6 * (time.perf_counter() - t0) / (n - 1)


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
        t0 = time.perf_counter()
        feed(est, steps)
        best = min(best, (time.perf_counter() - t0) / steps * 1e6)
    return best


def bench_speed_and_steering(steps: int = 5_000, repeats: int = 3) -> list[dict[str, float | str]]:
    """us per step of the speed KF (budget 15 us at 500 Hz) and the steering UKF (budget 50 us),
    each against a same-run baseline: a straightforward numpy Kalman step for the speed filter,
    the (numpy-Jacobian) EKF for the steering UKF."""
    import numpy as np

    from vecu.estimators.speed_kf import SpeedKalmanFilter
    from vecu.estimators.steering_filters import SteeringEKF, SteeringUKF
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
