"""Hernández 2005 Fig. 5 (sensitivity singular values of the LQG/LTR loop), Fig. 8 (power
spectra of the raw wheel speed and acceleration) and Fig. 11 (the same of the estimates)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vecu.estimators.speed.lqg_design import paper_design
from vecu.eval.speed import run_filter
from vecu.figures.common import power_db, pyplot, save
from vecu.plant.longitudinal import DT_S, simulate_speed
from vecu.units import MPS_PER_KMH


def make(out: Path, quick: bool = False) -> list[tuple[Path, str]]:
    plt = pyplot()
    design = paper_design()
    loop = design.loop
    ws = np.logspace(-2, 4, 400 if quick else 2000)
    n = loop.A.shape[0]
    sv = []
    for w in ws:
        L = loop.C @ np.linalg.solve(1j * w * np.eye(n) - loop.A, loop.B)
        S = np.linalg.inv(np.eye(L.shape[0]) + L)
        sv.append(np.linalg.svd(S, compute_uv=False))
    sv_db = 20 * np.log10(np.array(sv))
    fig, ax = plt.subplots(figsize=(8, 4))
    lines = ax.semilogx(ws, sv_db)
    for k, line in enumerate(lines):
        line.set_label(f"σ{k + 1}(S(jω))" + (" (largest)" if k == 0 else ""))
    ax.axhline(design.peak.db, color="r", ls=":", lw=0.8,
               label=f"peak {design.peak.db:.2f} dB (paper 2.41 dB)")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_xlabel("frequency (rad/s)")
    ax.set_ylabel("singular values of S (dB)")
    ax.set_title(f"Hernandez 2005 Fig. 5: sensitivity singular values, q = 100: peak "
                 f"{design.peak.db:.2f} dB at {design.peak.w_rad_s:.3g} rad/s (paper 2.41 dB)",
                 fontsize=9)
    p5 = save(fig, out / "speed_fig5_sensitivity.png")
    tr = simulate_speed(seed=1)
    v_hat, a_hat, _, _ = run_filter(tr)
    spectra = []
    for fig_no, label, v, a in ((8, "sensor readings", tr.wheel, tr.accel),
                                (11, "estimates", v_hat, a_hat)):
        fig, axes = plt.subplots(1, 2, figsize=(10, 4))
        for ax, x, unit in ((axes[0], v / MPS_PER_KMH, "speed"), (axes[1], a, "acceleration")):
            f, db = power_db(x, DT_S)
            ax.semilogx(f, db, lw=0.6)
            ax.set_xlabel("frequency (Hz)")
            ax.set_ylabel(f"{unit} power spectrum (dB)")
            hi = f > 20.0
            spectra.append(float(np.mean(db[hi])))
        fig.suptitle(f"Hernandez 2005 Fig. {fig_no}: power spectrum magnitude of the {label} "
                     "(simulated 84 km/h braking, 500 Hz)", fontsize=10)
        path = save(fig, out / f"speed_fig{fig_no}_spectrum_{'raw' if fig_no == 8 else 'est'}.png")
        spectra.append(path)  # type: ignore[arg-type]  # the PNG paths share the list with the dB values
    raw_v, raw_a, p8, est_v, est_a, p11 = spectra
    note = (f"mean power above 20 Hz: speed {raw_v:.1f} -> {est_v:.1f} dB, acceleration "
            f"{raw_a:.1f} -> {est_a:.1f} dB")
    return [(p5, f"peak {design.peak.db:.2f} dB (paper 2.41 dB)"), (p8, note), (p11, note)]
