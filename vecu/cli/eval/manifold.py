"""`vecu eval manifold`: the manifold filters and the 6-event CAC prediction (Table 1 analogue)."""

from __future__ import annotations

import argparse
import dataclasses
import json

from vecu import argtypes
from vecu.errors import BadArgumentError


def register(models: argparse._SubParsersAction) -> None:
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
