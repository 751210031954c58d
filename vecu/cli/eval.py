"""`vecu eval`: offline estimator accuracy against simulated truth (throttle now; more later)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import Any

from vecu import argtypes
from vecu.errors import BadArgumentError

DEFAULT_THROTTLE_FILTERS = ("ahsm", "arm", "agm", "open-loop", "production")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="score estimators offline against simulated truth",
                       description="Offline evaluation of state estimators on simulated plants.")
    models = p.add_subparsers(dest="model", required=True, metavar="MODEL")
    t = models.add_parser(
        "throttle", help="throttle angle from the wattmeter (Vargas et al. 2015)",
        description="Simulate the throttle plant and score each filter's theta estimate against "
                    "the true simulated angle (error = estimate - truth, after a 1000-step burn-in).")
    t.add_argument("--steps", type=argtypes.positive_int, default=200_000, metavar="N",
                   help="1 ms steps to simulate (default 200000)")
    t.add_argument("--noise-scale", type=argtypes.noise_scale, default=1.0, metavar="A",
                   help="process-noise scale alpha of plant and filters (1 = paper, default 1; "
                        f"0..{argtypes.NOISE_SCALE_MAX:g})")
    t.add_argument("--filters", default=None, metavar="LIST",
                   help="comma-separated estimator names (default "
                        f"{','.join(DEFAULT_THROTTLE_FILTERS)}; 'production' is skipped with a "
                        "warning if unavailable and not asked for explicitly)")
    t.add_argument("--seed", type=argtypes.seed, default=1, help="simulation seed (default 1)")
    t.add_argument("--json", action="store_true", help="print JSON instead of a table")
    t.set_defaults(func=main_throttle)
    s = models.add_parser(
        "speed", help="vehicle speed/acceleration from wheel speed + accelerometer (Hernandez 2005)",
        description="Simulate braking manoeuvres at 500 Hz and score the speed Kalman filter: RMS "
                    "improvement in dB over the raw wheel-speed sensor (speed) and the raw "
                    "accelerometer (acceleration).")
    s.add_argument("--manoeuvre", default="paper",
                   help="paper (84 km/h -> standstill), gentle, abs, launch_brake, or 'all'")
    s.add_argument("--runs", type=argtypes.positive_int, default=10, metavar="K",
                   help="manoeuvres per seed (default 10)")
    s.add_argument("--seed", type=argtypes.seed, default=1, help="simulation seed (default 1)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")
    s.set_defaults(func=main_speed)
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
    mf = models.add_parser(
        "manifold", help="intake manifold EKF/SDKF and 6-event cylinder-air-charge prediction",
        description="Run the 80 s US06-like profile(s) and print the Table 1 analogue: integrated "
                    "|dCAC| and dCAC^2 of the 6-event CAC prediction for direct measurements, "
                    "direct + open-loop temperature, EKF and SDKF, and us per event.")
    mf.add_argument("--seed", type=argtypes.seed, default=1, help="first profile seed (default 1)")
    mf.add_argument("--runs", type=argtypes.positive_int, default=1, metavar="K", help="profiles (default 1)")
    mf.add_argument("--stride", type=argtypes.positive_int, default=4,
                    help="predict at every n-th event (default 4; sums scaled back)")
    mf.add_argument("--no-dare", action="store_true", help="skip the full-DARE SDKF baseline")
    mf.add_argument("--duration", type=argtypes.finite, metavar="S",
                    help="truncate each 80 s profile to S seconds (quick checks)")
    mf.add_argument("--json", action="store_true", help="print JSON instead of a table")
    mf.set_defaults(func=main_manifold)
    cs = models.add_parser(
        "consistency", help="NEES / NIS of every estimator's own covariance against the truth",
        description="Run each estimator (throttle production PF, speed KF, steering UKF, manifold "
                    "SDKF) on independent held-out seeds and print its time-averaged NEES with "
                    "the chi-square 95 %% band of the mean over runs (chi2(runs*d)/runs), the "
                    "share of |z| > 2 and > 3, and the NIS where the filter has innovations.")
    cs.add_argument("--runs", type=argtypes.positive_int, default=10, metavar="N",
                    help="independent runs (seeds) per estimator (default 10)")
    cs.add_argument("--seed", type=argtypes.seed, default=1000,
                    help="first seed (default 1000: held out from tuning)")
    cs.add_argument("--mismatch", action="store_true",
                    help="plant and calibration differ (Dutka Table 2-like errors, docs/models.md)")
    cs.add_argument("--estimators", default=None, metavar="LIST",
                    help="comma-separated subset of throttle,speed,steering,manifold (default all)")
    cs.add_argument("--quick", action="store_true",
                    help="short runs (5 s throttle / 10 s steering / 5 s manifold): a smoke check, "
                         "not a verdict")
    cs.add_argument("--json", action="store_true", help="print JSON instead of a table")
    cs.set_defaults(func=main_consistency)


def _throttle_filters(text: str | None) -> list[str]:
    from vecu.estimators.registry import (
        THROTTLE_ESTIMATORS,
        EstimatorUnavailableError,
        make_throttle_estimator,
    )

    if text is None:
        names = list(DEFAULT_THROTTLE_FILTERS)
        try:
            make_throttle_estimator("production")
        except EstimatorUnavailableError as exc:
            print(f"vecu: warning: {exc}; skipping it", file=sys.stderr)
            names.remove("production")
        return names
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names:
        raise BadArgumentError("--filters: empty list")
    unknown = [s for s in names if s not in THROTTLE_ESTIMATORS]
    if unknown:
        raise BadArgumentError(f"--filters: unknown estimator(s) {', '.join(unknown)}; "
                               f"choose from {', '.join(THROTTLE_ESTIMATORS)}")
    if len(set(names)) != len(names):
        raise BadArgumentError("--filters: a name is repeated")
    return names


def main_throttle(args: argparse.Namespace) -> int:
    from vecu.eval.throttle import DEFAULT_BURN_IN, evaluate_throttle

    if args.steps <= DEFAULT_BURN_IN:
        raise BadArgumentError(f"--steps must exceed the {DEFAULT_BURN_IN}-step burn-in")
    names = _throttle_filters(args.filters)
    report = evaluate_throttle(names, steps=args.steps, noise_scale=args.noise_scale,
                               seed=args.seed)
    if args.json:
        print(json.dumps(dataclasses.asdict(report), indent=2))
    else:
        print(format_throttle_report(dataclasses.asdict(report)))
    return 0


def format_throttle_report(r: dict[str, Any]) -> str:
    """The table printed by `vecu eval throttle`."""
    lines = [
        (f"throttle: {r['steps']} steps (burn-in {r['burn_in']}), seed {r['seed']}, "
        f"noise scale {r['noise_scale']:g}; error = theta_hat - theta_true (deg)"),
        (f"spread of theta_true itself (error of a constant estimate, ignoring u and y): "
        f"{r['theta_true_std_deg']:.2f} deg"),
        f"{'filter':<14}{'mean':>8}{'std':>8}{'rms':>8}{'sigma':>8}{'us/step':>10}{'resets':>8}",
    ]
    for x in r["results"]:
        lines.append(f"{x['filter']:<14}{x['mean_deg']:>8.2f}{x['std_deg']:>8.2f}"
                     f"{x['rms_deg']:>8.2f}{x['mean_sigma_deg']:>8.2f}"
                     f"{x['us_per_step']:>10.1f}{x['resets']:>8d}")
    lines.append("sigma = mean of the filter's own sqrt(P_theta) (compare with std: "
                 "over-confidence)")
    return "\n".join(lines)


def main_speed(args: argparse.Namespace) -> int:
    from vecu.eval.speed import evaluate_speed
    from vecu.plant.longitudinal import MANOEUVRES

    names = list(MANOEUVRES) if args.manoeuvre == "all" else [args.manoeuvre]
    unknown = [m for m in names if m not in MANOEUVRES]
    if unknown:
        raise BadArgumentError(f"--manoeuvre: unknown {unknown[0]!r}; choose from "
                               f"{', '.join(MANOEUVRES)} or all")
    reports = [dataclasses.asdict(evaluate_speed(seed=args.seed, runs=args.runs, manoeuvre=m))
               for m in names]
    if args.json:
        print(json.dumps(reports, indent=2))
        return 0
    print(f"speed: {args.runs} runs per manoeuvre, seed {args.seed}; gain = 20 log10(raw RMS / "
          f"filter RMS), targets >= 15 / 15 / 6 dB")
    print(f"{'manoeuvre':<14}{'v>=5 km/h':>12}{'v<5 km/h':>11}{'accel':>9}{'us/step':>9}"
          f"{'resets':>8}")
    for r in reports:
        print(f"{r['manoeuvre']:<14}{r['speed_gain_high_db']:>+10.1f}dB{r['speed_gain_low_db']:>+9.1f}dB"
              f"{r['accel_gain_db']:>+7.1f}dB{r['us_per_step']:>9.1f}{r['resets']:>8d}")
    return 0


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


def main_manifold(args: argparse.Namespace) -> int:
    from vecu.eval.manifold import evaluate_manifold

    if args.duration is not None and not 1.0 <= args.duration <= 80.0:
        raise BadArgumentError(f"--duration: expected 1..80 s, got {args.duration}")
    r = dataclasses.asdict(evaluate_manifold(seed=args.seed, runs=args.runs, stride=args.stride,
                                             full_dare=not args.no_dare,
                                             duration_s=args.duration))
    if args.json:
        print(json.dumps(r, indent=2, default=str))
        return 0
    print(f"manifold: seeds {list(r['seeds'])}, {r['events']} events, CAC predicted 6 events "
          f"ahead at every {r['stride']}th event; ratios to direct (paper: 1 : 0.65 : 0.46 : 0.46)")
    print(f"{'method':<16}{'sum|dCAC| mg':>14}{'ratio':>8}{'sum dCAC^2':>14}{'ratio':>8}")
    for m in r["methods"]:
        print(f"{m['method']:<16}{m['abs_sum_mg']:>14.0f}{m['abs_ratio']:>8.3f}"
              f"{m['sq_sum_mg2']:>14.0f}{m['sq_ratio']:>8.3f}")
    print(f"{'filter':<16}{'us/event':>10}{'resets':>8}{'P_im kPa':>16}")
    for f in r["filters"]:
        print(f"{f['name']:<16}{f['us_per_event']:>10.0f}{f['resets']:>8d}"
              f"{f['p_im_min']:>8.1f}..{f['p_im_max']:<6.1f}")
    print(f"P_im truth {r['p_im_true_min']:.1f}..{r['p_im_true_max']:.1f} kPa, "
          f"in range: {r['p_im_range_ok']}")
    return 0


def main_consistency(args: argparse.Namespace) -> int:
    from vecu.eval.consistency import ESTIMATORS, QUICK, Sizes, evaluate_consistency, format_report

    names = list(ESTIMATORS) if args.estimators is None else [
        x.strip() for x in args.estimators.split(",") if x.strip()]
    unknown = [x for x in names if x not in ESTIMATORS]
    if not names or unknown:
        raise BadArgumentError(f"--estimators: expected names from {', '.join(ESTIMATORS)}, got "
                               f"{args.estimators!r}")
    rep = evaluate_consistency(names, runs=args.runs, seed=args.seed, mismatch=args.mismatch,
                               sizes=QUICK if args.quick else Sizes())
    if args.json:
        out = dataclasses.asdict(rep)
        for r, d in zip(rep.results, out["results"]):
            d.update(inside=r.inside, ok=r.ok)
        print(json.dumps(out, indent=2))
    else:
        print(format_report(rep))
    return 0
