"""`vecu eval speed`: the speed Kalman filter on simulated braking manoeuvres."""

from __future__ import annotations

import argparse
import dataclasses
import json

from vecu import argtypes
from vecu.errors import BadArgumentError


def register(models: argparse._SubParsersAction) -> None:
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
