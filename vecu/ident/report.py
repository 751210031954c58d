"""What `vecu identify throttle` prints and writes: the table, JSON, PARAMS.toml and Fig. 2."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from vecu.ident.throttle import ThrottleFit

ECU_MODEL = "ecu.throttle.model"


def params_sets(fit: ThrottleFit) -> dict[str, Any]:
    """The ECU calibration as parameter-tree paths (what PARAMS.toml's [set] holds)."""
    m = fit.model
    out: dict[str, Any] = {}
    for s, mode in enumerate(m.modes):
        for name in ("a12", "a21", "a22", "a23", "a32", "a33", "b", "c1", "c2", "c3"):
            out[f"{ECU_MODEL}.mode{s + 1}.{name}"] = round(float(getattr(mode, name)), 10)
    out[f"{ECU_MODEL}.mode_bounds_deg"] = [float(b) for b in m.mode_bounds_deg]
    out[f"{ECU_MODEL}.f_diag"] = [round(float(f), 10) for f in m.f_diag]
    out[f"{ECU_MODEL}.h_wattmeter"] = round(float(m.h_wattmeter), 10)
    out["ecu.throttle.noise_scale"] = 1.0  # F above is the identified per-step noise itself
    return out


def params_toml(fit: ThrottleFit, trace: str) -> str:
    """PARAMS.toml text: a [set] table of dotted tree paths (as a scenario's [set])."""
    lines = [f"# ECU throttle calibration identified by `vecu identify throttle` from {trace}",
             "# use: vecu run --params THIS.toml / vecu replay TRACE --params THIS.toml",
             "[set]"]
    for path, value in params_sets(fit).items():
        if isinstance(value, list):
            text = "[" + ", ".join(repr(float(v)) for v in value) + "]"
        else:
            text = repr(float(value))
        lines.append(f'"{path}" = {text}')
    return "\n".join(lines) + "\n"


SHORT_TRACE_S = 180.0  # below it, modes 1-2 intervals are too narrow (docs/reproduction.md)


def interval_note(fit: ThrottleFit) -> str | None:
    """The caveat a short trace's intervals carry, or None: on 60 s traces the Wald intervals of
    modes 1-2 are 1.1-2.2x too narrow (mode2.a22 / a23 cover the truth in 13-14 of 20 traces),
    on 180 s traces every parameter covers >= 18 of 20 (tests/ident/test_coverage.py)."""
    seconds = fit.n_samples / 1000.0
    if seconds >= SHORT_TRACE_S:
        return None
    return (f"modes 1-2 intervals are indicative only on a {seconds:g} s trace (too narrow below "
            f"{SHORT_TRACE_S:g} s: mode2.a22 / a23 held the truth in 13-14 of 20 60 s traces); "
            "record >= 3 min for them")


def fit_json(fit: ThrottleFit) -> dict[str, Any]:
    """Everything printed, as JSON-ready data."""
    return {
        "n_samples": fit.n_samples,
        "method": fit.method,
        "interval": {"kind": fit.interval, "level": 0.95, "hac_window": fit.hac_window,
                     "note": interval_note(fit)},
        "mode_samples": list(fit.mode_samples),
        "parameters": [{"name": e.name, "value": e.value, "ci95": e.ci95, "start": e.start,
                        "status": e.status} for e in fit.estimates],
        "mode_bounds_deg": list(fit.model.mode_bounds_deg),
        "mode_bounds_status": fit.bounds_status,
        "f_diag": list(fit.model.f_diag),
        "h_wattmeter": fit.model.h_wattmeter,
        "one_step_cost": {"start": fit.cost_start, "fit": fit.cost_fit},
        "tps_noise_deg": fit.tps_noise_deg,
        "free_run_mse": {"start": {"theta_deg2": fit.free_run_mse_start[0],
                                   "current_a2": fit.free_run_mse_start[1]},
                         "fit": {"theta_deg2": fit.free_run_mse_fit[0],
                                 "current_a2": fit.free_run_mse_fit[1]}},
        "residuals": {mode: {state: {"mean": r.mean, "std": r.std, "n": r.n}
                             for state, r in stats.items()}
                      for mode, stats in fit.residuals.items()},
        "params": params_sets(fit),
    }


def format_fit(fit: ThrottleFit) -> str:
    """The human-readable report."""
    out = [(f"throttle identification: {fit.n_samples} samples "
           f"({fit.n_samples / 1000:g} s at 1 kHz), per mode {', '.join(map(str, fit.mode_samples))}"),
           f"method: {fit.method}",
           (f"95 % CI: {fit.interval} (Bartlett window {fit.hac_window} samples), valid for correlated "
            "residuals"),
           *([f"note: {note}"] if (note := interval_note(fit)) else []),
           "", f"{'parameter':<11} {'value':>10} {'95 % CI':>18} {'start':>10}  status"]
    for e in fit.estimates:
        ci = (f"+-{e.ci95:.3g}" if e.ci95 is not None and math.isfinite(e.ci95) else "-")
        out.append(f"{e.name:<11} {e.value:>10.5g} {ci:>18} {e.start:>10.5g}  {e.status}")
    b = fit.model.mode_bounds_deg
    f = fit.model.f_diag
    out += ["", f"switching angles  {b[0]:g}, {b[1]:g} deg: {fit.bounds_status}",
            (f"noise per 1 ms    F = diag({f[0]:.4g}, 0, {f[2]:.4g}) (Table I sqrt 0.35 = 0.592, "
            f"sqrt 0.18 = 0.424), H = {fit.model.h_wattmeter:.4g} W (1), maximum likelihood; "
            f"TPS {fit.tps_noise_deg:g} deg"),
            (f"one-step cost     {fit.cost_start:.4g} (start) -> {fit.cost_fit:.4g} (fit), "
            "mean square weighted innovation (1 when the model fits)"),
            ("free-run error    (paper's criterion, w = 0, 3 blocks) theta "
            f"{math.sqrt(fit.free_run_mse_start[0]):.3g} -> {math.sqrt(fit.free_run_mse_fit[0]):.3g}"
            f" deg rms, |i| {math.sqrt(fit.free_run_mse_start[1]):.3g} -> "
            f"{math.sqrt(fit.free_run_mse_fit[1]):.3g} A rms"),
            "", "one-step residuals  mode   theta mean / std (deg)   current mean / std (A)"]
    for mode, st in fit.residuals.items():
        t, c = st["theta_deg"], st["current_a"]
        out.append(f"{'':<20}{mode:<7}{t.mean:>9.3f} / {t.std:<12.3f}{c.mean:>9.3f} / {c.std:.3f}")
    e_th, e_i = fit.free_run_theta_error, fit.free_run_current_error
    out.append(f"free-run bias (Fig. 2): theta {np.mean(e_th):.3g} deg, |i| {np.mean(e_i):.3g} A "
               "(paper: 1.5 deg, -0.12 A)")
    return "\n".join(out)


def plot_residuals(fit: ThrottleFit, path: str | Path, title: str = "") -> None:
    """Fig. 2 of the throttle seed: normalised histograms of the model error (angle, current)
    with the fitted Gaussians; top row the paper's free-run error, bottom row vecu's one-step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    rows = (("free-run (w = 0) error", fit.free_run_theta_error, fit.free_run_current_error),
            ("one-step residual", fit.theta_residual, fit.current_residual))
    for r, (label, e_th, e_i) in enumerate(rows):
        for c, (e, unit) in enumerate(((e_th, "angle error (deg)"), (e_i, "current error (A)"))):
            ax = axes[r][c]
            e = np.asarray(e)[np.isfinite(e)]
            mu, sd = float(np.mean(e)), float(np.std(e))
            ax.hist(e, bins=80, density=True, alpha=0.6)
            x = np.linspace(mu - 4 * sd, mu + 4 * sd, 200)
            ax.plot(x, np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * math.sqrt(2 * math.pi)), "r")
            ax.set_title(f"{label}: mean {mu:.3g}, var {sd * sd:.3g}", fontsize=9)
            ax.set_xlabel(unit)
    fig.suptitle(title or "Vargas 2015 Fig. 2: model error histograms with fitted Gaussians")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
