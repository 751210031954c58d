"""`vecu conformance run` end to end in a private network namespace: `vecu ecu` with each fault
on udp_multicast, a real tester (examples/testers/udsoncan_isotp.py: udsoncan + can-isotp),
judged from its exit status and the frames it sent; a tester that hangs is killed and judged
hung; the JUnit file has one case per fault with its rule and evidence, the HTML its table."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from vecu.live.netns import namespace_prefix

ROOT = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.skipif(namespace_prefix()[0] is None,
                                 reason=namespace_prefix()[1] or "n/a"), pytest.mark.slow]


def bench(tmp_path: Path, tester: str, faults: str, timeout: str = "20") -> tuple[
        subprocess.CompletedProcess[str], ET.Element]:
    junit = tmp_path / "out.xml"
    res = subprocess.run([sys.executable, "-m", "vecu", "conformance", "run", "--tester", tester,
                          "--faults", faults, "--timeout", timeout, "--junit", str(junit),
                          "--report", str(tmp_path / "report")],
                         check=False, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr + res.stdout
    return res, ET.parse(junit).getroot()


def cases(root: ET.Element) -> dict[str, ET.Element]:
    return {c.get("name"): c for c in root.iter("testcase")}


def test_a_real_tester_judged_by_what_it_sent(tmp_path):
    tester = f"{sys.executable} {ROOT / 'examples' / 'testers' / 'udsoncan_isotp.py'}"
    res, root = bench(tmp_path, tester, "pending=2,fc_overflow,functional_multi=1")
    c = cases(root)
    assert set(c) == {"pending", "fc_overflow", "functional_multi"}
    assert c["pending"].find("failure") is None  # udsoncan waits through 0x78
    assert "no new request during" in c["pending"].findtext("system-out")
    assert c["fc_overflow"].find("failure") is None  # can-isotp stops at OVFLW
    # one can-isotp stack listens to one response ID: no flow control to the second ECU
    fail = c["functional_multi"].find("failure")
    assert fail is not None and "no flow control to ['0x7E9']" in fail.text
    props = {p.get("name"): p.get("value") for p in c["fc_overflow"].iter("property")}
    assert props["verdict"] == "pass" and "N_BUFFER_OVFLW" in props["rule"]
    assert "2/3 faults" in res.stdout
    assert (tmp_path / "report" / "index.html").read_text().count("<tr") == 4


def test_a_hung_tester_is_killed_and_the_bench_goes_on(tmp_path):
    res, root = bench(tmp_path, "sleep 60", "no_response,wrong_sid", timeout="2")
    c = cases(root)
    for name in ("no_response", "wrong_sid"):
        assert c[name].find("failure").get("type") == "hung"
    assert "0/2 faults" in res.stdout
