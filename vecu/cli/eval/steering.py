"""`vecu eval steering`: the steering-wheel angle / side-slip estimators on the simulated manoeuvre."""

from __future__ import annotations

import argparse
import dataclasses
import json

from vecu import argtypes
from vecu.errors import BadArgumentError


def register(models: argparse._SubParsersAction) -> None:
    st = models.add_parser(
        "steering", help="steering-wheel angle and side-slip from yaw rate + lateral acceleration",
        description="Simulate the single-track vehicle on the 300 s manoeuvre and score EKF, UKF, "
                    "fixed-lag and full unscented RTS smoother against the true steering-wheel "
                    "angle (the SWA sensor itself is not used: the dead-sensor case).")
    st.add_argument("--seed", type=argtypes.seed, default=1, help="simulation seed (default 1)")
    st.add_argument("--duration", type=argtypes.finite, default=300.0, metavar="S", help="seconds (default 300)")
    st.add_argument("--lag", type=argtypes.positive, default=0.25, metavar="S", help="fixed lag (default 0.25 s)")
    st.add_argument("--mismatch", action="store_true",
                    help="filter with cornering stiffness -15 %% and a 0.3 deg/s gyro bias")
    st.add_argument("--json", action="store_true", help="print JSON instead of a table")
    st.set_defaults(func=main_steering)


def main_steering(args: argparse.Namespace) -> int:
    from vecu.eval.steering import evaluate_steering

    if not 1.0 <= args.duration <= 3600.0:
        raise BadArgumentError(f"--duration: expected 1..3600 s, got {args.duration}")
    if not 0.0 < args.lag < args.duration:
        raise BadArgumentError(f"--lag: expected 0 < lag < duration, got {args.lag}")
    r = dataclasses.asdict(evaluate_steering(seed=args.seed, duration_s=args.duration,
                                             lag_s=args.lag, mismatch=args.mismatch))
    if args.json:
        print(json.dumps(r, indent=2))
        return 0
    print(f"steering: {r['duration_s']:g} s, seed {r['seed']}, {r['samples']} samples"
          f"{', model mismatch' if r['mismatch'] else ''}; RMS vs truth, targets UKF <= 1.3 deg, "
          f"smoothers <= 0.4 deg")
    print(f"{'estimator':<28}{'SWA deg':>9}{'side-slip deg':>15}{'us/step':>9}")
    rows = [("EKF", "ekf", r["us_per_step_ekf"]), ("UKF (live)", "ukf", r["us_per_step_ukf"]),
            (f"fixed-lag smoother ({r['lag_s']:g} s)", "fixed_lag", r["us_per_step_fixed_lag"]),
            ("full RTS smoother (offline)", "smoother", r["us_per_sample_rts"])]
    for label, key, us in rows:
        print(f"{label:<28}{r[f'swa_rms_{key}_deg']:>9.3f}{r[f'beta_rms_{key}_deg']:>15.4f}{us:>9.1f}")
    print(f"{'steady-state inverse, no filter':<28}{r['swa_rms_inverse_deg']:>9.3f}")
    print(f"{'healthy SWA sensor':<28}{r['swa_rms_sensor_deg']:>9.3f}")
    return 0
