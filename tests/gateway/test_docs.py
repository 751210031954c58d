"""docs/gateway.md's quick start as written: `vecu ecu` and `vecu gateway` on udp_multicast in a
private network namespace, then the doc's first Python snippet, run unchanged, prints the
announcement and the ECU's VIN read through the gateway."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from vecu.live.netns import namespace_prefix, run_in_namespace

ROOT = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.skipif(namespace_prefix()[0] is None,
                                 reason=namespace_prefix()[1] or "n/a"),
              pytest.mark.alone]  # live processes on the wall clock
RUN = r'''
import subprocess, sys, time
from pathlib import Path
out = Path(sys.argv[1])
vecu = [sys.executable, "-m", "vecu"]
procs = []
try:
    for name, argv in (("ecu", ["ecu", "--sync-timeout", "0"]), ("gateway", ["gateway"])):
        procs.append(subprocess.Popen([*vecu, *argv, "--interface", "udp_multicast", "--quiet",
                                       "--no-status", "--ready-file", str(out / name),
                                       "--duration", "60"]))
        while not (out / name).exists():
            time.sleep(0.05)
    exec(sys.argv[2])
finally:
    for p in procs:
        p.terminate()
        p.wait(30)
'''


def _snippet() -> str:
    text = (ROOT / "docs" / "gateway.md").read_text()
    return re.search(r"```python\n(.*?)```", text, re.DOTALL).group(1)


def test_the_quick_start_snippet_reads_the_vin_through_the_gateway(tmp_path):
    res = run_in_namespace([sys.executable, "-c", RUN, str(tmp_path), _snippet()], timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[-2:] == ["1VECU00SIM0000001 0x1000", "1VECU00SIM0000001"]
