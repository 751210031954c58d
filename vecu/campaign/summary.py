"""Campaign statistics and the HTML report.

Per metric: n, mean with its 95 % confidence interval (a proportion's Wilson interval for a
true/false metric, a bootstrap one for a non-negative metric, Student t otherwise: see
vecu.campaign.breakdown), std, 5/50/95 % percentiles with distribution-free 95 % intervals
(order statistics, binomial); the same split by every categorical draw (e.g. the fault kind),
and the runs an alarm metric flags. Manifold campaigns add the Table 3 analogue (mean integrated
absolute / squared 6-event CAC error per method, ratios to both direct columns, share of runs
each filter beats both) and Fig. 4/5 analogue histograms.
"""

from __future__ import annotations

import html
import math
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from vecu.campaign.breakdown import (
    categorical_draws,
    flagged_runs,
    is_binary,
    mean_interval,
    significant,
    wilson,
)
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


def describe(x: np.ndarray, binary: bool = False) -> dict[str, Any]:
    """n, mean and its 95 % interval (kind: proportion, constant or continuous), std, extremes,
    5/50/95 % percentiles with their intervals (not for a proportion)."""
    n = len(x)
    if n == 0:
        return {"n": 0}
    mean = float(x.mean())
    sd = float(x.std(ddof=1)) if n > 1 else 0.0
    out: dict[str, Any] = {"n": n, "mean": mean}
    if binary:
        k = round(float(x.sum()))
        out.update(kind="proportion", successes=k, mean_ci95=list(wilson(k, n)),
                   ci_method="wilson")
    elif float(x.min()) == float(x.max()):
        out.update(kind="constant", mean_ci95=[mean, mean], ci_method="constant")
    else:
        ci, method = mean_interval(x)
        out.update(kind="continuous", mean_ci95=ci, ci_method=method)
    out.update(std=sd, min=float(x.min()), max=float(x.max()))
    if binary:  # the percentiles of true/false values are 0 or 1: the share says it all
        return out
    for q in (0.05, 0.5, 0.95):
        out[f"p{round(q * 100)}"] = float(np.quantile(x, q))
        out[f"p{round(q * 100)}_ci95"] = list(_quantile_ci(x, q))
    return out


def metric_stats(rows: list[dict[str, str]], name: str) -> dict[str, Any]:
    raw = [r.get(name, "") for r in rows if r["status"] == "ok" and r.get(name, "") != ""]
    return describe(column(rows, name), binary=is_binary(raw))


def summarise(spec: CampaignSpec, rows: list[dict[str, str]]) -> dict[str, Any]:
    ok = [r for r in rows if r["status"] == "ok"]
    metrics = metric_names(spec)
    out: dict[str, Any] = {
        "campaign": spec.name, "kind": spec.kind, "seed": spec.seed, "runs": spec.runs,
        "done": len(rows), "ok": len(ok), "failed": len(rows) - len(ok),
        "failed_runs": [{"run_id": int(r["run_id"]), "sim_seed": r["sim_seed"],
                         "error": r["error"]} for r in rows if r["status"] != "ok"][:20],
        "metrics": {m: metric_stats(rows, m) for m in metrics},
        # the same per value of each categorical draw: the campaign's question, answered
        "by": {col[5:]: {value: {"runs": len(part), "metrics": {m: metric_stats(part, m)
                                                                  for m in metrics}}
                         for value in values
                         if (part := [r for r in ok if r.get(col) == value])}
               for col, values in categorical_draws(spec)},
        "flagged_runs": flagged_runs(rows, metrics),
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


def _figure():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _hist_png(data: list[np.ndarray], labels: list[str], title: str, path: Path,
              panels: bool = False, xlabel: str = "") -> None:
    """Histograms of `data` on shared bins: overlaid, or (panels) one panel per array stacked
    on a shared x axis with its mean marked, as the paper's Figs. 4 and 5; xlabel: the metric
    (with its unit) the x axis carries."""
    plt = _figure()
    filled = [d for d in data if len(d)]
    allv = np.concatenate(filled) if filled else np.zeros(1)
    lo, hi = float(allv.min()), float(allv.max())
    # a positive metric over decades (latency: 1 ms for a dead sensor, seconds for a drift):
    # log-spaced bins on a log axis, or the fast ones all fall in the first bin
    log_x = lo > 0 and hi / lo >= 100
    bins = (np.geomspace(lo, hi, 40) if log_x
            else np.linspace(lo, hi if hi > lo else lo + 1.0, 40))
    if panels:
        fig, axes = plt.subplots(len(data), 1, figsize=(7, 1.7 * len(data) + 0.8),
                                 sharex=True, squeeze=False)
        for ax, n, d in zip(axes[:, 0], labels, data):
            if len(d):
                ax.hist(d, bins=bins, color="tab:blue", alpha=0.8)
                ax.axvline(float(d.mean()), color="k", linewidth=1.0)
            ax.set_ylabel("runs", fontsize=8)
            ax.set_title(f"{n}: {len(d)} runs, mean {significant(float(d.mean())) if len(d) else '-'}",
                         fontsize=9, loc="left")
        fig.suptitle(title, fontsize=10)
        axes[-1, 0].set_xlabel(xlabel or title, fontsize=9)
        if log_x:
            axes[-1, 0].set_xscale("log")
    else:
        fig, ax = plt.subplots(figsize=(7, 3.6))
        for n, d in zip(labels, data):
            if len(d):
                ax.hist(d, bins=bins, histtype="step", linewidth=1.4, label=n)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xlabel or title)
        ax.set_ylabel("runs")
        ax.legend(fontsize=8)
        if log_x:
            ax.set_xscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _bar_png(groups: list[tuple[str, dict[str, Any]]], title: str, path: Path) -> None:
    """A true/false metric: its share per group with the 95 % Wilson interval."""
    plt = _figure()
    fig, ax = plt.subplots(figsize=(7, 3.2))
    x = np.arange(len(groups))
    share = np.array([100 * d["mean"] for _, d in groups])
    lo = np.array([100 * d["mean_ci95"][0] for _, d in groups])
    hi = np.array([100 * d["mean_ci95"][1] for _, d in groups])
    ax.bar(x, share, color="tab:blue", alpha=0.8)
    ax.errorbar(x, share, yerr=[share - lo, hi - share], fmt="none", ecolor="k", capsize=4)
    for xi, (_, d), s in zip(x, groups, share):
        ax.text(xi, min(s + 3, 104), f"{d['successes']}/{d['n']}", ha="center", fontsize=8)
    ax.set_xticks(x, [g for g, _ in groups], fontsize=8)
    ax.set_ylim(0, 110)
    ax.set_ylabel("% of runs (95 % Wilson CI)")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return significant(v)
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return html.escape(str(v))


def _value(d: dict[str, Any]) -> str:
    """One metric in a cell: share or mean with its 95 % interval, 4 significant digits."""
    if not d.get("n"):
        return "-"
    if d["kind"] == "proportion":
        lo, hi = d["mean_ci95"]
        return (f"{significant(100 * d['mean'])} % ({d['successes']}/{d['n']}) "
                f"[{significant(100 * lo)}, {significant(100 * hi)}] %")
    if d["kind"] == "constant":
        return f"{significant(d['mean'])} (all runs)"
    lo, hi = d["mean_ci95"]
    return f"{significant(d['mean'])} [{significant(lo)}, {significant(hi)}]"


def _drive_figures(spec: CampaignSpec, rows: list[dict[str, str]], summary: dict[str, Any],
                   out: Path) -> list[tuple[str, str]]:
    """Per metric: bars for a true/false one, histograms (a panel per value of the first
    categorical draw, if any) for the others; nothing for a constant one."""
    figs = []
    ok = [r for r in rows if r["status"] == "ok"]
    cats = categorical_draws(spec)
    for m in metric_names(spec):
        d = summary["metrics"][m]
        if not d.get("n") or d["kind"] == "constant":
            continue
        name = f"hist_{m}.png"
        if cats:
            col, values = cats[0]
            by = summary["by"][col[5:]]
            present = [v for v in values if v in by]
        if d["kind"] == "proportion":
            groups = [("all runs", d)] + ([(v, by[v]["metrics"][m]) for v in present
                                           if by[v]["metrics"][m].get("n")] if cats else [])
            _bar_png(groups, f"{m}: share of runs" + (f", by {col[5:]}" if cats else ""),
                     out / name)
        elif cats:
            data = [column([r for r in ok if r.get(col) == v], m) for v in present]
            _hist_png(data, present, f"{m} by {col[5:]}", out / name, panels=True, xlabel=m)
        else:
            _hist_png([column(rows, m)], [m], m, out / name, xlabel=m)
        figs.append((name, m))
    return figs


def write_report(spec: CampaignSpec, rows: list[dict[str, str]], summary: dict[str, Any],
                 out: Path) -> None:
    """out/report.html: figures per metric (split by the categorical draws; per filter for
    manifold), the statistics overall and per categorical draw, the Table 3 analogue, the runs
    an alarm metric flags and the worst runs, each with its seed and its rerun command."""
    import shlex

    figs: list[tuple[str, str]] = []
    if spec.kind == "manifold":
        for k, fig in (("ise", "Fig. 4"), ("iae", "Fig. 5")):  # Dutka: 4 squared, 5 absolute
            name = f"hist_{k}.png"
            what = (f"{fig} analogue: integrated {'absolute' if k == 'iae' else 'squared'} "
                    "6-event CAC prediction error")
            names = [f"{m}_{k}" for m in METHODS]
            _hist_png([column(rows, n) for n in names], names, f"{what} ({len(rows)} runs)",
                      out / name, panels=True,
                      xlabel=f"integrated {'|error|' if k == 'iae' else 'error²'} of the 6-event "
                             "CAC prediction over the drive (Dutka 2006 Table 3's measure)")
            figs.append((name, what))
    else:
        figs = _drive_figures(spec, rows, summary, out)
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
    metrics = list(summary["metrics"])
    for path, groups in summary.get("by", {}).items():
        parts.append(f"<h2>By {html.escape(path)}</h2><p>mean [95 % CI]; a true/false metric: "
                     "share of runs [95 % Wilson CI]</p><table border=1 cellpadding=3><tr>"
                     f"<th>{html.escape(path)}</th><th>runs</th>"
                     + "".join(f"<th>{html.escape(m)}</th>" for m in metrics) + "</tr>")
        for value, g in groups.items():
            parts.append(f"<tr><td>{html.escape(value)}</td><td>{g['runs']}</td>" + "".join(
                f"<td>{_value(g['metrics'][m])}</td>" for m in metrics) + "</tr>")
        parts.append("</table>")
    parts += [f"<h3>{html.escape(t)}</h3><img src='{n}' alt='{html.escape(t)}'>"
              for n, t in figs]
    keys = ("n", "p5", "p5_ci95", "p50", "p50_ci95", "p95", "p95_ci95")
    parts.append("<h2>Statistics</h2><table border=1 cellpadding=3><tr><th>metric</th>"
                 "<th>mean or share [95 % CI]</th><th>CI method</th><th>std</th>"
                 + "".join(f"<th>{k}</th>" for k in keys) + "</tr>")
    for m, d in summary["metrics"].items():
        parts.append(f"<tr><td>{m}</td><td>{_value(d)}</td><td>{d.get('ci_method', '')}</td>"
                     f"<td>{_fmt(d.get('std', ''))}</td>"
                     + "".join(f"<td>{_fmt(d.get(k, ''))}</td>" for k in keys) + "</tr>")
    parts.append("</table>")
    draw_cols = [c for c in (rows[0] if rows else {}) if c.startswith("draw:")]
    by_id = {r["run_id"]: r for r in rows}

    def rerun(run_id: Any) -> str:
        return html.escape(shlex.join(["vecu", "campaign", "rerun", str(out), str(run_id)]))

    def draws(r: dict[str, str]) -> str:
        return "".join(f"<td>{html.escape(significant(r.get(c, '')))}</td>" for c in draw_cols)

    draw_heads = "".join(f"<th>{html.escape(c[5:])}</th>" for c in draw_cols)
    flagged = summary.get("flagged_runs", [])
    if flagged:
        parts.append(f"<h2>Runs an alarm flags ({len(flagged)})</h2><table border=1 "
                     f"cellpadding=3><tr><th>run</th><th>sim seed</th><th>alarms</th>{draw_heads}"
                     "<th>repeat it</th></tr>")
        for f in flagged:
            parts.append(f"<tr><td>{f['run_id']}</td><td>{f['sim_seed']}</td><td>"
                         f"{html.escape(', '.join(f['alarms']))}</td>"
                         f"{draws(by_id.get(str(f['run_id']), {}))}"
                         f"<td><code>{rerun(f['run_id'])}</code></td></tr>")
        parts.append("</table>")
    worst_key = "sdkf_iae" if spec.kind == "manifold" else next(
        (m for m in ("after_kill_rms_deg", "detection_latency_ms", "dtc_confirmations")
         if m in metric_names(spec)), metric_names(spec)[0])
    ranked = sorted((r for r in rows if r["status"] == "ok" and r.get(worst_key)),
                    key=lambda r: -float(r[worst_key]))[:10]
    parts.append(f"<h2>Worst runs by {worst_key}</h2><table border=1 cellpadding=3><tr>"
                 f"<th>run</th><th>sim seed</th><th>{worst_key}</th>{draw_heads}"
                 "<th>repeat it</th></tr>")
    for r in ranked:
        parts.append(f"<tr><td>{r['run_id']}</td><td>{r['sim_seed']}</td>"
                     f"<td>{_fmt(float(r[worst_key]))}</td>{draws(r)}"
                     f"<td><code>{rerun(r['run_id'])}</code></td></tr>")
    parts.append("</table>")
    if summary["failed_runs"]:
        parts.append("<h2>Failed runs</h2><ul>" + "".join(
            f"<li>run {f['run_id']} (seed {f['sim_seed']}): {html.escape(f['error'])} "
            f"<code>{rerun(f['run_id'])}</code></li>"
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
        lines.append("  metric: runs, mean [95 % confidence interval of the mean; a true/false "
                     "metric: its share]; p5 / p50 / p95 of the runs")
        for m, d in summary["metrics"].items():
            if d.get("n"):
                pct = (f"  p5 {d['p5']:.4g}  p50 {d['p50']:.4g}  p95 {d['p95']:.4g}"
                       if "p5" in d else "")
                lines.append(f"  {m:<22} n {d['n']:>5}  {_value(d)}{pct}")
        for path, groups in summary.get("by", {}).items():
            lines.append(f"by {path} (mean [95 % interval]):")
            for value, g in groups.items():
                cells = [f"{m} {_value(d)}" for m, d in g["metrics"].items()
                         if d.get("n") and d["kind"] != "constant"]
                lines.append(f"  {value:<14} {g['runs']:>4} runs: " + "; ".join(cells))
        if summary.get("flagged_runs"):
            lines.append("flagged by an alarm: " + ", ".join(
                f"run {f['run_id']} ({', '.join(f['alarms'])})" for f in summary["flagged_runs"]))
    return "\n".join(lines)
