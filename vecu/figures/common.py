"""Matplotlib set-up shared by the figure modules (Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    pyplot().close(fig)
    return path


def power_db(x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectrum magnitude 20 log10 |FFT| of x (mean removed): (Hz, dB)."""
    x = np.asarray(x, dtype=float)
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(x.size)))
    f = np.fft.rfftfreq(x.size, dt_s)
    return f[1:], 20.0 * np.log10(np.maximum(spec[1:], 1e-12))
