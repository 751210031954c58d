"""`vecu eval consistency`: every estimator's own covariance against the simulated truth (NEES,
NIS, |z| tails over held-out seeds), across the ECU functions."""

from __future__ import annotations

import argparse
import dataclasses
import json

from vecu import argtypes
from vecu.errors import BadArgumentError


def register(models: argparse._SubParsersAction) -> None:
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
