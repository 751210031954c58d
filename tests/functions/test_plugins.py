"""Installed plug-ins (entry-point group `vecu.functions`): a package's entry point makes its
function part of every command; a broken one is one warning naming it, and vecu runs on. The
packages are metadata-only distributions on a temporary sys.path entry (what pip leaves in
site-packages: NAME-VERSION.dist-info with METADATA and entry_points.txt), used by subprocesses
so that this process's registry stays as it is."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _dist(site: Path, name: str, version: str, entries: dict[str, str]) -> None:
    info = site / f"{name}-{version}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(
        "[vecu.functions]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()))


def _vecu(site: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "VECU_KERNELS": "python",
           "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    return subprocess.run([sys.executable, "-m", "vecu", *argv], capture_output=True, text=True,
                          env=env, cwd=site, timeout=300, check=False)


def test_installed_plugins_are_listed_and_run_and_a_broken_one_is_one_line(tmp_path):
    site = tmp_path / "site"
    _dist(site, "vecu_toy", "1.2.3", {"toy": "tests.functions.toy:SPEC"})
    _dist(site, "vecu_broken", "0.1", {"broken": "no_such_module_here:SPEC",
                                       "notaspec": "json:dumps"})
    res = _vecu(site, "plugins", "--json")
    assert res.returncode == 0, res.stderr
    found = {p["name"]: p for p in json.loads(res.stdout)}
    assert (found["toy"]["package"], found["toy"]["version"], found["toy"]["error"]) == (
        "vecu_toy", "1.2.3", None)
    assert "ModuleNotFoundError" in found["broken"]["error"]
    assert "not an EcuFunctionSpec" in found["notaspec"]["error"]
    warnings = [ln for ln in res.stderr.splitlines() if "not loaded" in ln]
    assert len(warnings) == 2 and "'broken' (vecu_broken 0.1" in warnings[0]

    summary = tmp_path / "run.json"
    res = _vecu(site, "run", "--duration", "0.3", "--summary", str(summary))
    assert res.returncode == 0, res.stderr
    assert "toy: level RMS error" in res.stdout  # the plug-in's own summary line
    assert json.loads(summary.read_text())["toy"]["estimates_sent"] == 30
    assert sum("not loaded" in ln for ln in res.stderr.splitlines()) == 2  # once each

    res = _vecu(site, "params", "ecu.throttle.estimator")  # a command without functions
    assert res.returncode == 0 and "ecu.throttle.estimator" in res.stdout
