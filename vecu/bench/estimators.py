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
