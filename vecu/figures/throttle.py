"""Vargas 2015 Fig. 2 (model error histograms, §III-B identification) and Fig. 3 (measured vs
estimated position) from vecu's simulated throttle body at the paper's noise (alpha = 1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vecu.estimators.registry import make_throttle_estimator
from vecu.figures.common import pyplot, save
from vecu.ident.report import plot_residuals
from vecu.ident.throttle import identify_throttle
from vecu.ident.trace import ThrottleData
from vecu.plant.throttle import simulate


def make(out: Path, quick: bool = False) -> list[tuple[Path, str]]:
    steps = 8_000 if quick else 30_000
    tr = simulate(steps, seed=1, noise_scale=1.0)
    tps = tr.theta + 0.036 * np.random.default_rng(1).standard_normal(steps)
    fit = identify_throttle(ThrottleData("simulated", tr.u, tr.y, tps))
    p2 = out / "throttle_fig2_model_error.png"
    plot_residuals(fit, p2, "Vargas 2015 Fig. 2: model error, simulated Table I throttle "
                            f"(alpha = 1, {steps / 1000:g} s)")
    e_th = fit.free_run_theta_error
    note2 = (f"free-run bias {np.mean(e_th):.2f} deg (paper 1.5), F identified diag("
             f"{fit.model.f_diag[0]:.3f}, 0, {fit.model.f_diag[2]:.3f}) (paper 0.592, 0.424)")
    n3 = min(steps, 5_000 if quick else 20_000)
    est = {name: np.empty(n3) for name in ("production", "ahsm")}
    for name, arr in est.items():
        f = make_throttle_estimator(name, 1.0)
        u_prev = 0.0
        for k in range(n3):
            f.step(u_prev, float(tr.y[k]))
            u_prev = float(tr.u[k])
            arr[k] = f.theta_deg
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(10, 4))
    t = np.arange(n3) / 1000.0
    ax.plot(t, tr.theta[:n3], "k", lw=1.0, label="position (simulated truth)")
    ax.plot(t, est["ahsm"], lw=0.7, alpha=0.8, label="AHSM UKF (paper)")
    ax.plot(t, est["production"], lw=0.7, alpha=0.8, label="production particle filter")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("throttle angle (deg)")
    ax.legend(loc="upper right", fontsize=8)
    err = {k: v[1000:] - tr.theta[1000:n3] for k, v in est.items()}
    ax.set_title("Vargas 2015 Fig. 3: position and its estimate from the wattmeter only "
                 f"(AHSM {np.mean(err['ahsm']):.1f} +- {np.std(err['ahsm']):.1f} deg, production "
                 f"{np.mean(err['production']):.1f} +- {np.std(err['production']):.1f} deg)",
                 fontsize=9)
    p3 = save(fig, out / "throttle_fig3_position_estimate.png")
    note3 = ", ".join(f"{k} error {np.mean(v):.2f} +- {np.std(v):.2f} deg" for k, v in err.items())
    return [(p2, note2), (p3, note3)]
