"""`vecu eval`: offline estimator accuracy against simulated truth (throttle now; more later)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import Any

from vecu.cli import UserInputError

DEFAULT_THROTTLE_FILTERS = ("ahsm", "arm", "agm", "open-loop", "production")


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def _non_negative_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v >= 0.0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return v


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="score estimators offline against simulated truth",
                       description="Offline evaluation of state estimators on simulated plants.")
    models = p.add_subparsers(dest="model", required=True, metavar="MODEL")
    t = models.add_parser(
        "throttle", help="throttle angle from the wattmeter (Vargas et al. 2015)",
        description="Simulate the throttle plant and score each filter's theta estimate against "
                    "the true simulated angle (error = estimate - truth, after a 1000-step burn-in).")
    t.add_argument("--steps", type=_positive_int, default=200_000, metavar="N",
                   help="1 ms steps to simulate (default 200000)")
    t.add_argument("--noise-scale", type=_non_negative_float, default=1.0, metavar="A",
                   help="process-noise scale alpha of plant and filters (1 = paper, default 1)")
    t.add_argument("--filters", default=None, metavar="LIST",
                   help="comma-separated estimator names (default "
                        f"{','.join(DEFAULT_THROTTLE_FILTERS)}; 'production' is skipped with a "
                        "warning if unavailable and not asked for explicitly)")
    t.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")
    t.add_argument("--json", action="store_true", help="print JSON instead of a table")
    t.set_defaults(func=main_throttle)
    s = models.add_parser(
        "speed", help="vehicle speed/acceleration from wheel speed + accelerometer (Hernandez 2005)",
        description="Simulate braking manoeuvres at 500 Hz and score the speed Kalman filter: RMS "
                    "improvement in dB over the raw wheel-speed sensor (speed) and the raw "
                    "accelerometer (acceleration).")
    s.add_argument("--manoeuvre", default="paper",
                   help="paper (84 km/h -> standstill), gentle, abs, launch_brake, or 'all'")
    s.add_argument("--runs", type=_positive_int, default=10, metavar="K",
                   help="manoeuvres per seed (default 10)")
    s.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")
    s.add_argument("--json", action="store_true", help="print JSON instead of a table")
    s.set_defaults(func=main_speed)


def _throttle_filters(text: str | None) -> list[str]:
    from vecu.estimators.registry import (
        THROTTLE_ESTIMATORS, EstimatorUnavailableError, make_throttle_estimator,
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
        raise UserInputError("--filters: empty list")
    unknown = [s for s in names if s not in THROTTLE_ESTIMATORS]
    if unknown:
        raise UserInputError(f"--filters: unknown estimator(s) {', '.join(unknown)}; "
                             f"choose from {', '.join(THROTTLE_ESTIMATORS)}")
    if len(set(names)) != len(names):
        raise UserInputError("--filters: a name is repeated")
    return names


def main_throttle(args: argparse.Namespace) -> int:
    from vecu.estimators.registry import EstimatorUnavailableError
    from vecu.eval.throttle import DEFAULT_BURN_IN, evaluate_throttle

    if args.steps <= DEFAULT_BURN_IN:
        raise UserInputError(f"--steps must exceed the {DEFAULT_BURN_IN}-step burn-in")
    names = _throttle_filters(args.filters)
    try:
        report = evaluate_throttle(names, steps=args.steps, noise_scale=args.noise_scale,
                                   seed=args.seed)
    except EstimatorUnavailableError as exc:
        raise UserInputError(str(exc)) from exc
    if args.json:
        print(json.dumps(dataclasses.asdict(report), indent=2))
    else:
        print(format_throttle_report(dataclasses.asdict(report)))
    return 0


def format_throttle_report(r: dict[str, Any]) -> str:
    """The table printed by `vecu eval throttle`."""
    lines = [
        f"throttle: {r['steps']} steps (burn-in {r['burn_in']}), seed {r['seed']}, "
        f"noise scale {r['noise_scale']:g}; error = theta_hat - theta_true (deg)",
        f"spread of theta_true itself (error of a constant estimate, ignoring u and y): "
        f"{r['theta_true_std_deg']:.2f} deg",
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
        raise UserInputError(f"--manoeuvre: unknown {unknown[0]!r}; choose from "
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
