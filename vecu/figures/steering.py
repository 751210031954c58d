"""Khalid Fig. 2 (side-slip angle and its estimate) and Fig. 3 (steering angle and its
estimate): the UKF on vecu's simulated manoeuvre (vecu eval steering's run)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vecu.estimators.steering.filters import SteeringUKF
from vecu.estimators.steering.model import SteeringModel
from vecu.figures.common import pyplot, save
from vecu.plant.lateral import ManoeuvreConfig, simulate_lateral
from vecu.units import RAD_PER_DEG


def make(out: Path, quick: bool = False) -> list[tuple[Path, str]]:
    duration = 60.0 if quick else 300.0
    tr = simulate_lateral(1, ManoeuvreConfig(duration_s=duration))
    ukf = SteeringUKF(SteeringModel())
    n = tr.t.size
    swa, beta = np.empty(n), np.empty(n)
    for k in range(n):
        ukf.step(float(tr.meas_vx[k]), float(tr.meas_r[k]), float(tr.meas_ay[k]))
        swa[k], beta[k] = ukf.swa_rad, ukf.side_slip_rad
    d = 1.0 / RAD_PER_DEG
    plt = pyplot()
    done = []
    for fig_no, name, truth, est in ((2, "side-slip angle", tr.beta, beta),
                                     (3, "steering-wheel angle", tr.swa, swa)):
        e = (est - truth) * d
        rms = float(np.sqrt(np.mean(e ** 2)))
        fig, ax = plt.subplots(figsize=(10, 4))
        ax.plot(tr.t, truth * d, "k", lw=0.8, label="true (simulated)")
        ax.plot(tr.t, est * d, "r", lw=0.6, alpha=0.8, label="UKF estimate")
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"{name} (deg)")
        ax.legend(fontsize=8)
        ax.set_title(f"Khalid Fig. {fig_no}: evaluation of the {name} and its estimate "
                     f"(RMS error {rms:.3g} deg, {duration:g} s)", fontsize=9)
        tag = "sideslip" if fig_no == 2 else "steering_angle"
        done.append((save(fig, out / f"steering_fig{fig_no}_{tag}.png"), f"RMS error {rms:.3g} deg"))
    return done
