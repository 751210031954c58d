"""Replay plot: what the ECU broadcast on the trace, against the trace's truth frames if any."""

from __future__ import annotations

import numpy as np

from vecu import functions


def plot_replay(series: dict[str, list[tuple[float, float, float]]], path: str,
                title: str) -> None:
    """One panel per function that produced estimates: broadcast value and truth."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(s.name, s.label or s.name) for s in functions.specs() if series.get(s.name)]
    fig, axes = plt.subplots(max(len(panels), 1), 1, figsize=(10, 2.4 * max(len(panels), 1)),
                             sharex=True, squeeze=False)
    for ax, (key, label) in zip(axes[:, 0], panels):
        rows = np.asarray(series[key], dtype=float)
        ax.plot(rows[:, 0], rows[:, 1], lw=0.8, label="ECU broadcast")
        if np.any(np.isfinite(rows[:, 2])):
            ax.plot(rows[:, 0], rows[:, 2], lw=0.8, ls="--", label="truth (trace)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    if not panels:
        axes[0, 0].text(0.5, 0.5, "no estimates: see the summary", ha="center",
                        transform=axes[0, 0].transAxes)
    axes[-1, 0].set_xlabel("trace time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
