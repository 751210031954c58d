"""A fleet's summary.json, report.html (the scenario report's page: a row per trace, its
criteria, and a fleet plot) and JUnit XML (the scenario writer: one test case per trace), from
runs.csv and the per-trace files under DIR/traces/."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

from vecu.fleet.task import TRACES_DIR
from vecu.scenario.criteria import CriterionResult, ScenarioOutcome

PLOT = "fleet.png"
REPORT = "report.html"


def _load(path: Path) -> Any:
    return json.loads(path.read_text()) if path.is_file() else None


def _diff_criteria(diff: dict[str, Any]) -> list[CriterionResult]:
    """The diff as criteria: each signal's share outside its tolerance, the unpaired frames,
    each E2E-protected message's protocol check."""
    out = [CriterionResult(f"diff {name}", f"{s['outside']}/{s['pairs']} outside (max "
                           f"{s['max_abs']:.4g}, RMS {s['rms']:.4g}"
                           + (f", first at {s['first_divergence_s']:.3f} s)"
                              if s["first_divergence_s"] is not None else ")"),
                           f"|d| <= {s['tolerance']:.4g}", s["passed"])
           for name, s in diff["signals"].items()]
    unpaired = diff["recorded_only"] + diff["replayed_only"]
    fail_unpaired = any("not replayed" in r for r in diff["reasons"])
    out.append(CriterionResult("diff frames paired", f"{diff['recorded_only']} recorded only, "
                               f"{diff['replayed_only']} replayed only", f"{unpaired} unpaired",
                               not fail_unpaired))
    out += [CriterionResult(f"E2E {name}", f"replay: CRC {e['replayed_crc_errors']}, counter "
                            f"{e['replayed_counter_errors']} errors; recording: CRC "
                            f"{e['recorded_crc_errors']}, counter {e['recorded_counter_errors']}",
                            "no replay error", e["passed"]) for name, e in diff["e2e"].items()]
    return out


def outcomes(rows: list[dict[str, str]], out: Path) -> list[ScenarioOutcome]:
    """One ScenarioOutcome per trace: its diff and criteria results, times, error."""
    res = []
    for r in rows:
        base = out / TRACES_DIR / r["name"]
        summary = _load(base.with_name(base.name + ".summary.json")) or {}
        crit: list[CriterionResult] = []
        diff = _load(base.with_name(base.name + ".diff.json")) if r["diff"] else None
        if diff is not None:
            crit += _diff_criteria(diff)
        for c in (_load(base.with_name(base.name + ".criteria.json")) or []
                  if r["status"] != "error" else []):
            crit.append(CriterionResult(c["name"], c["measured"], c["limit"], c["passed"]))
        res.append(ScenarioOutcome(
            name=r["name"], path=r["trace"], description=f"verdict: {r['verdict']}",
            passed=r["status"] == "ok", criteria=tuple(crit),
            sim_s=float(r["trace_duration_s"] or 0.0),
            wall_s=float(summary.get("wall_time_s") or 0.0),
            x_realtime=float(summary.get("x_realtime") or 0.0),
            error=r["error"] or None if r["status"] == "error" else None))
    return res


def summarise(rows: list[dict[str, str]]) -> dict[str, Any]:
    """The fleet in numbers (no wall time: the same bytes whatever the workers)."""
    status = Counter(r["status"] for r in rows)
    signals = Counter(s for r in rows for s in r["diff_failed_signals"].split())
    return {
        "traces": len(rows), "ok": status["ok"], "fail": status["fail"],
        "error": status["error"], "verdicts": dict(sorted(Counter(r["verdict"]
                                                                  for r in rows).items())),
        "trace_duration_s": round(sum(float(r["trace_duration_s"] or 0) for r in rows), 6),
        "frames_read": sum(int(r["frames_read"] or 0) for r in rows),
        "signals_failed": dict(sorted(signals.items())),  # signal -> traces where it failed
        "errors": [{"trace": r["trace"], "error": r["error"]} for r in rows
                   if r["status"] == "error"],
        "rows": rows,
    }


def _plot(rows: list[dict[str, str]], path: Path) -> str:
    """Per trace: signals outside tolerance (with --diff) or estimate frames sent, coloured by
    status."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    diffed = any(r["diff"] for r in rows)
    values = [len(r["diff_failed_signals"].split()) if diffed else int(r["estimates_sent"] or 0)
              for r in rows]
    colour = {"ok": "tab:green", "fail": "tab:red", "error": "tab:gray"}
    fig, ax = plt.subplots(figsize=(7, min(0.25 * len(rows) + 1.2, 40)))
    y = range(len(rows))
    ax.barh(list(y), values, color=[colour.get(r["status"], "k") for r in rows])
    ax.set_yticks(list(y), [r["name"] for r in rows], fontsize=7)
    ax.invert_yaxis()
    what = "signals outside tolerance" if diffed else "estimate frames sent"
    ax.set_xlabel(what)
    ax.set_title(f"{len(rows)} traces: {what} (green ok, red failed, grey error)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return what


def write_outputs(rows: list[dict[str, str]], out: Path, junit: str | None) -> dict[str, Any]:
    from vecu.scenario.report import write_html, write_junit

    summary = summarise(rows)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    items = outcomes(rows, out)
    head = ""
    if rows:
        what = _plot(rows, out / PLOT)
        head = f'<p><img src="{PLOT}" alt="{what} per trace"></p>'
    write_html(items, str(out), title="vecu fleet replay", file=REPORT, head=head,
               noun="traces")
    if junit:
        write_junit(items, junit, suite_name="vecu replay", classname="vecu.replay")
    return summary
