"""Campaign statistics and the HTML report.

Per metric: n, mean with its 95 % confidence interval (Student t), std, 5/50/95 % percentiles
with distribution-free 95 % intervals (order statistics, binomial). Manifold campaigns add the
Table 3 analogue (mean integrated absolute / squared 6-event CAC error per method, ratios to both
direct columns, share of runs each filter beats both) and Fig. 4/5 analogue histograms.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from vecu.campaign.spec import CampaignSpec
from vecu.campaign.studies import FILTERS, METHODS, metric_names

PAPER_TABLE3 = {  # Dutka 2006 Table 3: mean integrated |error| / error^2 over 2000 runs
    "direct_ol": (3646.0, 13265.0), "direct": (4850.0, 23385.0),
    "sdkf": (3222.0, 11487.0), "ekf": (3230.0, 11516.0),
}


def _num(v: str) -> float | None:
    if v in ("", None):
        return None
    if v in ("true", "false"):
        return 1.0 if v == "true" else 0.0
    try:
        return float(v)
    except ValueError:
        return None


def column(rows: list[dict[str, str]], name: str) -> np.ndarray:
    vals = [_num(r.get(name, "")) for r in rows if r["status"] == "ok"]
    return np.array([v for v in vals if v is not None and math.isfinite(v)], dtype=float)


def _quantile_ci(x: np.ndarray, q: float) -> tuple[float, float]:
    n = len(x)
    if n < 2:
        return (math.nan, math.nan)
    s = np.sort(x)
    lo = int(stats.binom.ppf(0.025, n, q))
    hi = int(stats.binom.ppf(0.975, n, q))
    return float(s[max(lo - 1, 0)]), float(s[min(hi, n - 1)])


def describe(x: np.ndarray) -> dict[str, Any]:
    n = len(x)
    if n == 0:
        return {"n": 0}
    mean = float(x.mean())
    sd = float(x.std(ddof=1)) if n > 1 else 0.0
    half = float(stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n)) if n > 1 else math.nan
    out: dict[str, Any] = {"n": n, "mean": mean, "mean_ci95": [mean - half, mean + half],
                           "std": sd, "min": float(x.min()), "max": float(x.max())}
    for q in (0.05, 0.5, 0.95):
        out[f"p{round(q * 100)}"] = float(np.quantile(x, q))
        out[f"p{round(q * 100)}_ci95"] = list(_quantile_ci(x, q))
    return out


def summarise(spec: CampaignSpec, rows: list[dict[str, str]]) -> dict[str, Any]:
    ok = [r for r in rows if r["status"] == "ok"]
    out: dict[str, Any] = {
        "campaign": spec.name, "kind": spec.kind, "seed": spec.seed, "runs": spec.runs,
        "done": len(rows), "ok": len(ok), "failed": len(rows) - len(ok),
        "failed_runs": [{"run_id": int(r["run_id"]), "sim_seed": r["sim_seed"],
                         "error": r["error"]} for r in rows if r["status"] != "ok"][:20],
        "metrics": {m: describe(column(rows, m)) for m in metric_names(spec)},
    }
    if spec.kind == "manifold" and ok:
        out["table3"] = table3(rows)
    return out


def table3(rows: list[dict[str, str]]) -> dict[str, Any]:
    """The Table 3 analogue: means, ratios to both direct columns, per-run win shares."""
    ok = [r for r in rows if r["status"] == "ok"]
    val = {(m, k): np.array([float(r[f"{m}_{k}"]) for r in ok]) for m in METHODS
           for k in ("iae", "ise")}
    res: dict[str, Any] = {}
    for m in METHODS:
        res[m] = {}
        for k in ("iae", "ise"):
            mean = float(val[(m, k)].mean())
            res[m][k] = {"mean": mean, "ratio_to_direct_ol": mean / float(val[("direct_ol", k)].mean()),
                         "ratio_to_direct": mean / float(val[("direct", k)].mean()),
                         "paper": PAPER_TABLE3.get(m, (None, None))[0 if k == "iae" else 1]}
        if m in FILTERS:
            wins = (val[(m, "iae")] < val[("direct_ol", "iae")]) & (
                val[(m, "iae")] < val[("direct", "iae")])
            res[m]["beats_both_direct_share"] = float(wins.mean())
    return res


def _hist_png(spec: CampaignSpec, rows: list[dict[str, str]], names: list[str], title: str,
              path: Path, panels: bool = False) -> None:
    """Histograms of the named columns on shared bins: overlaid, or (panels) one panel per
    column stacked on a shared x axis with its mean marked, as the paper's Figs. 4 and 5."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = [column(rows, n) for n in names]
    allv = np.concatenate([d for d in data if len(d)]) if any(len(d) for d in data) else np.zeros(1)
    bins = np.linspace(float(allv.min()), float(allv.max()) + 1e-12, 40)
    if panels:
        fig, axes = plt.subplots(len(names), 1, figsize=(7, 1.7 * len(names) + 0.8),
                                 sharex=True, squeeze=False)
        for ax, n, d in zip(axes[:, 0], names, data):
            if len(d):
                ax.hist(d, bins=bins, color="tab:blue", alpha=0.8)
                ax.axvline(float(d.mean()), color="k", linewidth=1.0)
            ax.set_ylabel("runs", fontsize=8)
            ax.set_title(f"{n} (mean {float(d.mean()) if len(d) else math.nan:.4g})",
                         fontsize=9, loc="left")
        fig.suptitle(title, fontsize=10)
    else:
        fig, ax = plt.subplots(figsize=(7, 3.6))
        for n, d in zip(names, data):
            if len(d):
                ax.hist(d, bins=bins, histtype="step", linewidth=1.4, label=n)
        ax.set_title(title, fontsize=10)
        ax.set_ylabel("runs")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return html.escape(str(v))


def write_report(spec: CampaignSpec, rows: list[dict[str, str]], summary: dict[str, Any],
                 out: Path) -> None:
    """out/report.html: histograms per metric (per filter for manifold), the statistics table,
    the Table 3 analogue and the worst runs with their seeds and drawn parameters."""
    figs: list[tuple[str, str]] = []
    if spec.kind == "manifold":
        for k, fig in (("ise", "Fig. 4"), ("iae", "Fig. 5")):  # Dutka: 4 squared, 5 absolute
            name = f"hist_{k}.png"
            what = (f"{fig} analogue: integrated {'absolute' if k == 'iae' else 'squared'} "
                    "6-event CAC prediction error")
            _hist_png(spec, rows, [f"{m}_{k}" for m in METHODS], f"{what} ({len(rows)} runs)",
                      out / name, panels=True)
            figs.append((name, what))
    else:
        for m in metric_names(spec):
            if summary["metrics"][m].get("n", 0):
                name = f"hist_{m}.png"
                _hist_png(spec, rows, [m], m, out / name)
                figs.append((name, m))
    head = (f"<html><head><meta charset='utf-8'><title>{html.escape(spec.name)}</title></head>"
            f"<body><h1>{html.escape(spec.name)}</h1><p>{html.escape(spec.description)}</p>"
            f"<p>kind {spec.kind}, seed {spec.seed}, {summary['done']}/{spec.runs} runs done, "
            f"{summary['failed']} failed</p>")
    parts = [head]
    if "table3" in summary:
        parts.append("<h2>Table 3 analogue</h2><table border=1 cellpadding=3><tr><th>method</th>"
                     "<th>mean int. |err| (mg)</th><th>/ direct OL-T</th><th>/ direct</th>"
                     "<th>paper</th><th>mean int. err^2 (mg^2)</th><th>/ direct OL-T</th>"
                     "<th>/ direct</th><th>paper</th><th>beats both direct</th></tr>")
        for m, r in summary["table3"].items():
            cells = []
            for k in ("iae", "ise"):
                cells += [r[k]["mean"], r[k]["ratio_to_direct_ol"], r[k]["ratio_to_direct"],
                          r[k]["paper"]]
            share = r.get("beats_both_direct_share")
            cells.append("" if share is None else f"{100 * share:.1f} %")
            parts.append(f"<tr><td>{m}</td>" + "".join(f"<td>{_fmt(c)}</td>" for c in cells)
                         + "</tr>")
        parts.append("</table>")
    parts += [f"<h3>{html.escape(t)}</h3><img src='{n}'>" for n, t in figs]
    keys = ("n", "mean", "mean_ci95", "std", "p5", "p5_ci95", "p50", "p50_ci95", "p95", "p95_ci95")
    parts.append("<h2>Statistics</h2><table border=1 cellpadding=3><tr><th>metric</th>"
                 + "".join(f"<th>{k}</th>" for k in keys) + "</tr>")
    for m, d in summary["metrics"].items():
        parts.append(f"<tr><td>{m}</td>" + "".join(f"<td>{_fmt(d.get(k, ''))}</td>" for k in keys)
                     + "</tr>")
    parts.append("</table>")
    worst_key = "sdkf_iae" if spec.kind == "manifold" else next(
        (m for m in ("after_kill_rms_deg", "detection_latency_ms", "dtc_confirmations")
         if m in metric_names(spec)), metric_names(spec)[0])
    ranked = sorted((r for r in rows if r["status"] == "ok" and r.get(worst_key)),
                    key=lambda r: -float(r[worst_key]))[:10]
    draw_cols = [c for c in (rows[0] if rows else {}) if c.startswith("draw:")]
    parts.append(f"<h2>Worst runs by {worst_key}</h2><p>repeat one: <code>vecu campaign rerun "
                 f"DIR RUN_ID</code></p><table border=1 cellpadding=3><tr><th>run</th><th>sim seed"
                 f"</th><th>{worst_key}</th>" + "".join(f"<th>{html.escape(c[5:])}</th>"
                                                         for c in draw_cols) + "</tr>")
    for r in ranked:
        parts.append(f"<tr><td>{r['run_id']}</td><td>{r['sim_seed']}</td><td>{_fmt(float(r[worst_key]))}"
                     "</td>" + "".join(f"<td>{html.escape(r[c])}</td>" for c in draw_cols) + "</tr>")
    parts.append("</table>")
    if summary["failed_runs"]:
        parts.append("<h2>Failed runs</h2><ul>" + "".join(
            f"<li>run {f['run_id']} (seed {f['sim_seed']}): {html.escape(f['error'])}</li>"
            for f in summary["failed_runs"]) + "</ul>")
    (out / "report.html").write_text("".join(parts) + "</body></html>\n")


def format_summary(summary: dict[str, Any]) -> str:
    head = (f"campaign {summary['campaign']} ({summary['kind']}): {summary['ok']} ok, "
            f"{summary['failed']} failed of {summary['runs']}")
    lines = [head]
    if "table3" in summary:
        lines.append(f"{'method':<10}{'mean int|err|':>14}{'/dir OL-T':>10}{'/direct':>9}"
                     f"{'mean int err^2':>16}{'/dir OL-T':>10}{'/direct':>9}{'beats both':>11}")
        for m, r in summary["table3"].items():
            share = r.get("beats_both_direct_share")
            lines.append(f"{m:<10}{r['iae']['mean']:>14.1f}{r['iae']['ratio_to_direct_ol']:>10.3f}"
                         f"{r['iae']['ratio_to_direct']:>9.3f}{r['ise']['mean']:>16.1f}"
                         f"{r['ise']['ratio_to_direct_ol']:>10.3f}{r['ise']['ratio_to_direct']:>9.3f}"
                         f"{'' if share is None else f'{100 * share:.1f} %':>11}")
        lines.append("paper (Table 3, 2000 runs): direct OL-T 3646 / 13265, direct 4850 / 23385, "
                     "SDKF 3222 / 11487, EKF 3230 / 11516 (ratios SDKF 0.88 / 0.87 to OL-T)")
    else:
        for m, d in summary["metrics"].items():
            if d.get("n"):
                lo, hi = d["mean_ci95"]
                lines.append(f"  {m:<22} n {d['n']:>5}  mean {d['mean']:.4g} (95 % CI {lo:.4g}.."
                             f"{hi:.4g})  p5 {d['p5']:.4g}  p50 {d['p50']:.4g}  p95 {d['p95']:.4g}")
    return "\n".join(lines)
