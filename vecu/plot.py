"""Truth-vs-estimate plots (matplotlib, no display needed)."""

from __future__ import annotations

from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vecu.runner import Series  # noqa: E402


def plot_throttle_run(series: Series, summary: dict[str, Any], path: str) -> None:
    """Two panels: angles (truth, TPS, broadcast, estimate ± 2 sigma) and the broadcast error."""
    t = series.t_s
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(11, 7), sharex=True,
                                   gridspec_kw={"height_ratios": [3, 1.3]})
    ax1.fill_between(t, series.theta_est - 2 * series.theta_est_std,
                     series.theta_est + 2 * series.theta_est_std, color="tab:orange", alpha=0.18,
                     lw=0, label="estimate ± 2σ")
    ax1.plot(t, series.theta_true, color="black", lw=1.0, label="true θ")
    ax1.plot(t, series.theta_sensor, color="tab:blue", lw=0.6, alpha=0.7, label="TPS sensor")
    ax1.plot(t, series.theta_est, color="tab:orange", lw=0.8, label="estimate (hot standby)")
    ax1.plot(t, series.theta_broadcast, color="tab:red", lw=0.8, ls="--", label="broadcast")
    th = summary["throttle"]
    on_est = series.source == 1
    if on_est.any():
        ax1.fill_between(t, 0, 1, where=on_est, transform=ax1.get_xaxis_transform(),
                         color="tab:red", alpha=0.07, lw=0, label="broadcasting estimate")
    if th["kill_time_s"] is not None:
        for ax in (ax1, ax2):
            ax.axvline(th["kill_time_s"], color="tab:purple", lw=1.2, ls=":")
        ax1.text(th["kill_time_s"], 92, f" TPS {th['fault']}", color="tab:purple", va="bottom")
    ax1.set_ylim(-5, 100)
    ax1.set_ylabel("throttle angle (deg)")
    ax1.legend(loc="upper left", fontsize=8, ncol=3)
    ax1.set_title(f"vecu run — seed {summary['config']['seed']}, α = "
                  f"{summary['config']['noise_scale']}, estimator {th['estimator']}")
    ax2.plot(t, series.theta_broadcast - series.theta_true, color="tab:red", lw=0.6)
    ax2.axhline(0, color="black", lw=0.5)
    ax2.set_ylabel("broadcast − true (deg)")
    ax2.set_xlabel("time (s)")
    err = np.abs(series.theta_broadcast - series.theta_true)
    ax2.set_ylim(-max(5.0, float(np.nanpercentile(err, 99.5)) * 1.2),
                 max(5.0, float(np.nanpercentile(err, 99.5)) * 1.2))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
