"""The statistics a campaign's question needs (issue 29): intervals that fit each metric, the
results split by every categorical draw, and the runs an alarm metric flags.

- A binary metric (true/false) is a proportion: Wilson score interval (scipy's binomtest),
  never outside [0, 1].
- A non-negative metric's mean: percentile bootstrap (seeded, so summary.json is reproducible),
  never below its smallest value; a metric that takes negative values: Student t.
- A constant metric says so (no interval, no histogram).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import stats

from vecu.campaign.spec import CampaignSpec

BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20251126
# metrics whose non-zero value flags a run for a look (a run's alarm, not its measurement)
ALARM_METRICS = ("false_alarm", "nan_outputs")


def wilson(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of k successes in n."""
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)


def mean_interval(x: np.ndarray) -> tuple[list[float], str]:
    """95 % interval of the mean of x and its method: bootstrap for non-negative x, else t."""
    n = len(x)
    mean = float(x.mean())
    if n < 2:
        return [math.nan, math.nan], "none"
    if float(x.min()) >= 0.0:
        res = stats.bootstrap((x,), np.mean, confidence_level=0.95,
                              n_resamples=BOOTSTRAP_RESAMPLES, method="percentile",
                              random_state=np.random.default_rng(BOOTSTRAP_SEED))
        ci = res.confidence_interval
        return [float(ci.low), float(ci.high)], "bootstrap"
    half = float(stats.t.ppf(0.975, n - 1) * x.std(ddof=1) / math.sqrt(n))
    return [mean - half, mean + half], "student-t"


def is_binary(raw: list[str]) -> bool:
    """A metric recorded as true/false in runs.csv."""
    return bool(raw) and all(v in ("true", "false") for v in raw)


def categorical_draws(spec: CampaignSpec) -> list[tuple[str, list[str]]]:
    """(runs.csv column, its values as written there) of each draw that picks among choices
    (e.g. draw:fault.kind)."""
    return [(f"draw:{v.path}", [str(c) for c in v.choices]) for v in spec.vary
            if v.dist == "choice"]


def flagged_runs(rows: list[dict[str, str]], metrics: tuple[str, ...]) -> list[dict[str, Any]]:
    """Runs with a non-zero alarm metric: run id, sim seed, the alarms."""
    alarms = [m for m in ALARM_METRICS if m in metrics]
    out = []
    for r in rows:
        if r["status"] != "ok":
            continue
        hit = [m for m in alarms if r.get(m) not in ("", "false", "0", "0.0", None)]
        if hit:
            out.append({"run_id": int(r["run_id"]), "sim_seed": r["sim_seed"], "alarms": hit})
    return out


def significant(v: Any, digits: int = 4) -> str:
    """A number (or a number as text, e.g. a drawn value from runs.csv) in `digits`
    significant digits; anything else as it is."""
    if isinstance(v, str):
        try:
            v = float(v)
        except ValueError:
            return v
    if isinstance(v, bool) or not isinstance(v, float | int):
        return str(v)
    return f"{v:.{digits}g}"
