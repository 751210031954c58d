"""docs/gateway.md "Routing between buses": the quick start's database and config, written out
as the doc shows them, and its command run as written, print the documented per-route lines and
log the documented vehicle-bus frames."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

from .routing_setup import DATA

ROOT = Path(__file__).resolve().parents[2]


def _blocks(kind: str) -> list[str]:
    text = (ROOT / "docs" / "gateway.md").read_text()
    section = text[text.index("## Routing between buses"):]
    return re.findall(rf"```{kind}\n(.*?)```", section, re.DOTALL)


def test_the_quick_start_runs_as_written(tmp_path):
    (dbc,), toml, command = _blocks("dbc"), _blocks("toml")[0], _blocks("sh")[0]  # the first
    assert dbc == (DATA / "body.dbc").read_text()  # the tests' database is the doc's
    (tmp_path / "body.dbc").write_text(dbc)
    (tmp_path / "gw.toml").write_text(toml)
    argv = shlex.split(command)
    assert argv[0] == "vecu"
    done = subprocess.run([sys.executable, "-m", "vecu", *argv[1:]], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300, check=False,
                          env={**os.environ, "VECU_KERNELS": "python"})
    assert done.returncode == 0, done.stderr
    printed, logged = _blocks("text")[:2]
    assert [ln for ln in done.stdout.splitlines() if ln.startswith("gateway ")] == \
        printed.splitlines()
    vehicle = [ln for ln in (tmp_path / "both.log").read_text().splitlines() if " vehicle " in ln]
    assert vehicle[:3] == logged.splitlines()
