"""Truth-vs-estimate plots (matplotlib, no display needed)."""

from __future__ import annotations

from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from vecu import functions
from vecu.functions.throttle import ThrottleSeries
from vecu.runner import RunResult
from vecu.summary import RunSummary


def plot_run(result: RunResult, path: str) -> None:
    """Throttle panels (angles, broadcast error) and a panel per other function with a series
    (its registry entry's `plot`)."""
    series, summary = result.throttle_series, result.report
    extra = [(spec.plot, data) for spec in functions.specs()  # each other function's panel
             if spec.plot is not None and spec.name != "throttle"
             and (data := result.series_of(spec.name)) is not None
             and not (isinstance(data, np.ndarray) and data.size == 0)]
    n = 2 + len(extra)
    fig, axes = plt.subplots(n, 1, figsize=(11, 7 + 2.6 * (n - 2)), sharex=True,
                             gridspec_kw={"height_ratios": [3, 1.3] + [2] * len(extra)})
    _plot_throttle(series, summary, axes[0], axes[1])
    for ax, (plot, data) in zip(axes[2:], extra):
        plot(data, ax)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_throttle(series: ThrottleSeries, summary: RunSummary, ax1: Any, ax2: Any) -> None:
    """Angles (truth, TPS, broadcast, estimate ± 2 sigma) and the broadcast error."""
    t = series.t_s
    ax1.fill_between(t, series.theta_est - 2 * series.theta_est_std,
                     series.theta_est + 2 * series.theta_est_std, color="tab:orange", alpha=0.18,
                     lw=0, label="estimate ± 2σ")
    ax1.plot(t, series.theta_true, color="black", lw=1.0, label="true θ")
    ax1.plot(t, series.theta_sensor, color="tab:blue", lw=0.6, alpha=0.7, label="TPS sensor")
    ax1.plot(t, series.theta_est, color="tab:orange", lw=0.8, label="estimate (hot standby)")
    ax1.plot(t, series.theta_broadcast, color="tab:red", lw=0.8, ls="--", label="broadcast")
    th = summary.throttle
    kill_s = th.detection.kill_time_s
    on_est = series.source == 1
    if on_est.any():
        ax1.fill_between(t, 0, 1, where=on_est, transform=ax1.get_xaxis_transform(),
                         color="tab:red", alpha=0.07, lw=0, label="broadcasting estimate")
    if kill_s is not None:
        for ax in (ax1, ax2):
            ax.axvline(kill_s, color="tab:purple", lw=1.2, ls=":")
        ax1.text(kill_s, 92, f" TPS {th.fault}", color="tab:purple", va="bottom")
    ax1.set_ylim(-5, 100)
    ax1.set_ylabel("throttle angle (deg)")
    ax1.legend(loc="upper left", fontsize=8, ncol=3)
    ax1.set_title(f"vecu run — seed {summary.config['seed']}, α = "
                  f"{summary.config['noise_scale']}, estimator {th.estimator}")
    ax2.plot(t, series.theta_broadcast - series.theta_true, color="tab:red", lw=0.6)
    ax2.axhline(0, color="black", lw=0.5)
    ax2.set_ylabel("broadcast − true (deg)")
    err = np.abs(series.theta_broadcast - series.theta_true)
    ax2.set_ylim(-max(5.0, float(np.nanpercentile(err, 99.5)) * 1.2),
                 max(5.0, float(np.nanpercentile(err, 99.5)) * 1.2))
