"""Scenario reports: JUnit XML for CI, a dependency-free HTML page, PNG plots per scenario."""

from __future__ import annotations

import hashlib
import html
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from vecu import functions
from vecu.faults import parse_site
from vecu.runner import RunResult
from vecu.scenario.criteria import ScenarioOutcome, fault_windows
from vecu.scenario.loader import Scenario

SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}")


def plot_file_name(name: str) -> str:
    """The file of a scenario's plot in the report directory: NAME.png when the name is a plain
    file name (letters, digits, '.', '_', '-'; no leading dot; up to 100 characters), else the
    name with every other run of characters as '_' and 8 hex digits of its SHA-1, so that a '/'
    or '..' stays inside the directory and different names never share a file."""
    if SAFE_NAME.fullmatch(name):
        return f"{name}.png"
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._-")[:80] or "scenario"
    digest = hashlib.sha1(name.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    return f"{stem}-{digest}.png"


def write_junit(outcomes: list[ScenarioOutcome], path: str, suite_name: str = "vecu scenarios",
                classname: str = "vecu.scenarios") -> None:
    """One <testcase> per scenario (per trace of a fleet replay, vecu.fleet); each failed
    criterion is a <failure> line."""
    failures = sum(1 for o in outcomes if not o.passed and not o.error)
    errors = sum(1 for o in outcomes if o.error)
    suite = ET.Element("testsuite", name=suite_name, tests=str(len(outcomes)),
                       failures=str(failures), errors=str(errors),
                       time=f"{sum(o.wall_s for o in outcomes):.3f}")
    for o in outcomes:
        case = ET.SubElement(suite, "testcase", classname=classname, name=o.name,
                             file=o.path, time=f"{o.wall_s:.3f}")
        props = ET.SubElement(case, "properties")
        for key, value in (("sim_time_s", f"{o.sim_s:g}"), ("x_realtime", f"{o.x_realtime:.2f}"),
                           ("x_realtime_cpu", f"{o.x_realtime_cpu:.2f}")):
            ET.SubElement(props, "property", name=key, value=value)
        if o.error:
            ET.SubElement(case, "error", message=o.error).text = o.error
        elif not o.passed:
            text = "\n".join(f"{c.name}: {c.measured} (limit {c.limit})" for c in o.failures)
            ET.SubElement(case, "failure", message=f"{len(o.failures)} criteria failed").text = text
        ET.SubElement(case, "system-out").text = "\n".join(
            f"{'PASS' if c.passed else 'FAIL'} {c.name}: {c.measured} (limit {c.limit})"
            for c in o.criteria) + f"\n{o.x_realtime:.1f}x real time"
    root = ET.Element("testsuites", tests=suite.get("tests"), failures=suite.get("failures"),
                      errors=suite.get("errors"))
    root.append(suite)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:left}}.pass{{color:#070}}.fail{{color:#b00}}
img{{max-width:100%}}</style></head><body>
<h1>{title}</h1>
<p>{passed} of {total} {noun} passed; {sim:.1f} s simulated in {wall:.1f} s wall.</p>
{head}
<table><tr><th>{item}</th><th>result</th><th>simulated</th><th>x real time (wall)</th>
<th>x real time (CPU)</th><th>file</th></tr>
{rows}</table>
{sections}
</body></html>
"""


def write_html(outcomes: list[ScenarioOutcome], report_dir: str, title: str = "vecu scenario report",
               file: str = "index.html", head: str = "", noun: str = "scenarios") -> str:
    """report_dir/FILE (plots are written next to it by the runner); head: HTML after the
    totals (a fleet replay's plot)."""
    out = Path(report_dir)
    out.mkdir(parents=True, exist_ok=True)
    esc = html.escape
    rows, sections = [], []
    for o in outcomes:
        cls, verdict = ("pass", "PASS") if o.passed else ("fail", "ERROR" if o.error else "FAIL")
        rows.append(f'<tr><td><a href="#{esc(o.name)}">{esc(o.name)}</a></td>'
                    f'<td class="{cls}">{verdict}</td><td>{o.sim_s:g} s</td>'
                    f"<td>{o.x_realtime:.1f}</td><td>{o.x_realtime_cpu:.1f}</td>"
                    f"<td>{esc(o.path)}</td></tr>")
        crit = "".join(f'<tr><td>{esc(c.name)}</td><td>{esc(c.measured)}</td>'
                       f'<td>{esc(c.limit)}</td><td class="{"pass" if c.passed else "fail"}">'
                       f'{"pass" if c.passed else "FAIL"}</td></tr>' for c in o.criteria)
        events = "".join(f"<li>{e['t_s']:.3f} s: {esc(str(e['target']))} {esc(e['kind'])}"
                         f"{' ' + esc(', '.join(e['ended'])) if e.get('ended') else ''}</li>"
                         for e in o.fault_events)
        dtcs = "".join(_dtc_table(name, d) for name, d in (o.diagnostics or {}).items())
        img = (f'<p><img src="{esc(Path(o.plot).name)}" alt="{esc(o.name)} plot"></p>'
               if o.plot else "")
        sections.append(
            f'<h2 id="{esc(o.name)}">{esc(o.name)} — <span class="{cls}">{verdict}</span></h2>'
            f"<p>{esc(o.description)}</p>"
            + (f'<p class="fail">{esc(o.error)}</p>' if o.error else "")
            + f"<table><tr><th>criterion</th><th>measured</th><th>limit</th><th></th></tr>{crit}"
            f"</table><p>Fault events:</p><ul>{events}</ul><p>DTCs:</p>{dtcs}{img}")
    page = _PAGE.format(title=html.escape(title), noun=noun, item=noun.rstrip("s"), head=head,
                        passed=sum(o.passed for o in outcomes), total=len(outcomes),
                        sim=sum(o.sim_s for o in outcomes), wall=sum(o.wall_s for o in outcomes),
                        rows="\n".join(rows), sections="\n".join(sections))
    path = out / file
    path.write_text(page, encoding="utf-8")
    return str(path)


def plot_scenario(scenario: Scenario, result: RunResult, path: str) -> None:
    """Truth, sensor, estimate and broadcast per diagnosed sensor of the run's functions (its
    series' panel()); fault windows on the function's input frames shaded."""
    panels: list[tuple[str, str, Any]] = [
        (short, fn, series) for short, (fn, _) in functions.sensors().items()
        if (series := result.series_of(fn)) is not None]
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 3.2 * len(panels) + 0.6), sharex=True,
                             squeeze=False)
    diag = result.report.diagnostics
    for ax, (name, fn, s) in zip(axes[:, 0], panels):
        ylabel, lines = s.panel()
        ax.set_ylabel(ylabel)
        for y, label, color, ls in lines:
            ax.plot(s.t_s, y, color=color, lw=0.8, ls=ls, label=label,
                    alpha=0.6 if "sensor" in label else 1.0)
        mine = {inp.message for inp in functions.spec(fn).inputs.values()}
        windows = [w for w, f in zip(fault_windows(scenario), scenario.config.faults)
                   if parse_site(f.target).message in mine]
        for k, (t0, t1, label) in enumerate(windows):
            ax.axvspan(t0, t1, color="tab:purple", alpha=0.12, lw=0,
                       label="fault window" if k == 0 else None)
            if True:
                ax.text(t0, 1.0, " " + label, transform=ax.get_xaxis_transform(), fontsize=7,
                        va="bottom", color="tab:purple")
        for t, st in diag.get(name, {}).get("status_history", []):
            ax.axvline(t, color="tab:green" if st == "ok" else "tab:red", lw=0.8, ls=":")
        finite = np.concatenate([y[np.isfinite(y)] for y, *_ in lines]) if lines else []
        if len(finite):
            lo, hi = np.percentile(finite, [0.5, 99.5])
            pad = max(1.0, 0.1 * (hi - lo))
            ax.set_ylim(lo - pad, hi + pad)
        ax.legend(loc="upper right", fontsize=7, ncol=5)
    axes[-1, 0].set_xlabel("time (s)  —  dotted: diagnosis status changes (red fault, green ok)")
    fig.suptitle(f"{scenario.name}: seed {scenario.config.seed}, estimator "
                 f"{scenario.config.params.ecu.throttle.estimator}", y=0.995, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _dtc_table(sensor: str, diag: dict) -> str:
    """One sensor's DTC: its final state and its history (time, state) as a table."""
    esc = html.escape
    history = diag.get("dtc_history", [])
    rows = "".join(f"<tr><td>{t:.3f} s</td><td>{esc(str(state))}</td></tr>"
                   for t, state in history)
    return (f"<p>{esc(sensor)}: {esc(str(diag['dtc']))} at the end"
            + (f"</p><table><tr><th>time</th><th>DTC state</th></tr>{rows}</table>"
               if history else "; no change during the run</p>"))
