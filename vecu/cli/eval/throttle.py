"""`vecu eval throttle`: the throttle estimators against the simulated throttle body."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from typing import Any

from vecu import argtypes
from vecu.errors import BadArgumentError

DEFAULT_THROTTLE_FILTERS = ("ahsm", "arm", "agm", "open-loop", "production")


def register(models: argparse._SubParsersAction) -> None:
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
