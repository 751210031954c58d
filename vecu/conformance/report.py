"""The bench's outputs: a JUnit XML file (one test case per fault: the rule, the verdict, the
evidence) and an HTML table."""

from __future__ import annotations

import html
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

from vecu.conformance.judge import Verdict
from vecu.uds.diag_faults.catalogue import FAULTS


def write_junit(path: Path, verdicts: Sequence[Verdict], tester: str) -> None:
    bad = sum(v.verdict != "pass" for v in verdicts)
    suite = ET.Element("testsuite", name="vecu conformance", tests=str(len(verdicts)),
                       failures=str(bad), errors="0",
                       time=f"{sum(v.seconds for v in verdicts):.3f}")
    props = ET.SubElement(suite, "properties")
    ET.SubElement(props, "property", name="tester", value=tester)
    for v in verdicts:
        f = FAULTS[v.fault]
        case = ET.SubElement(suite, "testcase", name=v.fault, classname=f"conformance.{f.layer}",
                             time=f"{v.seconds:.3f}")
        cp = ET.SubElement(case, "properties")
        for key, value in (("rule", v.rule), ("clause", f.clause), ("expected", v.expected),
                           ("verdict", v.verdict), ("value", f"{v.value:g}")):
            ET.SubElement(cp, "property", name=key, value=value)
        if v.verdict != "pass":
            fail = ET.SubElement(case, "failure", message=f"{v.verdict}: {v.rule}",
                                 type=v.verdict)
            fail.text = v.evidence
        ET.SubElement(case, "system-out").text = v.evidence
    ET.ElementTree(suite).write(path, encoding="utf-8", xml_declaration=True)


def write_html(directory: Path, verdicts: Sequence[Verdict], tester: str) -> Path:
    directory.mkdir(parents=True, exist_ok=True)
    colour = {"pass": "#cfc", "fail": "#fcc", "hung": "#fc9", "error": "#ccc"}
    rows = "\n".join(
        f"<tr style='background:{colour[v.verdict]}'><td>{html.escape(v.fault)}</td>"
        f"<td>{html.escape(FAULTS[v.fault].layer)}</td><td><b>{v.verdict}</b></td>"
        f"<td>{'' if v.exit_code is None else v.exit_code}</td>"
        f"<td>{html.escape(v.rule)}</td><td>{html.escape(FAULTS[v.fault].clause)}</td>"
        f"<td>{html.escape(v.evidence)}</td></tr>" for v in verdicts)
    passed = sum(v.verdict == "pass" for v in verdicts)
    page = (f"<!doctype html><meta charset='utf-8'><title>vecu conformance</title>"
            f"<h1>vecu conformance: {passed}/{len(verdicts)} pass</h1>"
            f"<p>tester: <code>{html.escape(tester)}</code></p>"
            "<table border='1' cellpadding='4' style='border-collapse:collapse'>"
            "<tr><th>fault</th><th>layer</th><th>verdict</th><th>exit</th>"
            "<th>the client must</th><th>clause</th><th>evidence</th></tr>\n"
            f"{rows}</table>\n")
    out = directory / "index.html"
    out.write_text(page)
    return out
