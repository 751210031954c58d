"""The Python entry point and the pytest plugin, used as a user uses them: vecu.simulate with
the CLI's defaults returns the typed summary; docs/python.md's example test file runs under
pytest with the plugin (as its pytest11 entry point loads it from an installed vecu)."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import vecu
from vecu.cli import main as cli_main
from vecu.config import RunConfig
from vecu.errors import BadArgumentError
from vecu.runner import run
from vecu.summary import RunSummary, to_json

ROOT = Path(__file__).resolve().parents[1]


def test_a_run_config_of_any_duration_kills_the_tps_at_half_of_it():
    assert RunConfig().kill_tps_at_s == 5.0 and RunConfig(duration_s=1.0).kill_tps_at_s == 0.5
    assert RunConfig(duration_s=1.0, kill_tps_at_s=None).kill_tps_at_s is None
    report = run(RunConfig(duration_s=1.0)).report  # raised before: the kill stayed at 5 s
    assert report.throttle.detection.kill_time_s == 0.5


def test_simulate_is_vecu_run_with_the_same_defaults_and_a_typed_summary(tmp_path):
    summary = vecu.simulate(1.0, seed=3, sets={"ecu.throttle.tps_monitor.plaus_debounce": 20})
    assert isinstance(summary, RunSummary) and dataclasses.is_dataclass(summary)
    with pytest.raises(dataclasses.FrozenInstanceError):
        summary.ticks = 0  # type: ignore[misc]  # frozen: the point of the test
    out = tmp_path / "cli.json"
    assert cli_main(["run", "--duration", "1", "--seed", "3", "--quiet", "--set",
                     "ecu.throttle.tps_monitor.plaus_debounce=20", "--summary", str(out)]) == 0
    cli = json.loads(out.read_text())
    mine = json.loads(json.dumps(to_json(summary)))
    for volatile in ("wall_time_s", "x_realtime", "kernel_load_s", "tasks"):  # host timings
        cli.pop(volatile, None), mine.pop(volatile, None)
    for timed in (cli, mine):
        for key in [k for k in timed["manifold"] if k.endswith("_us_per_event")]:
            timed["manifold"].pop(key)
    assert mine == cli  # same run, same summary
    with pytest.raises(BadArgumentError, match="--fmu and --fmu-map go together"):
        vecu.simulate(1.0, fmu="x.fmu")


@pytest.mark.slow
def test_the_documented_example_test_file_passes_under_the_plugin(tmp_path):
    env = {**os.environ, "VECU_KERNELS": "python", "PYTEST_DISABLE_PLUGIN_AUTOLOAD": "1",
           "PYTHONPATH": str(ROOT)}
    example = tmp_path / "test_my_ecu.py"  # the user's own test file, in their own folder
    example.write_text((ROOT / "examples" / "python" / "test_my_ecu.py").read_text())
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "vecu.pytest_plugin", "-q",
                           "-p", "no:cacheprovider", str(example)], capture_output=True,
                          text=True, cwd=tmp_path, env=env, timeout=600, check=False)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "2 passed" in done.stdout
