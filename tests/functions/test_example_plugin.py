"""The example plug-in package examples/vecu-oil-temperature, installed by pip (into a
temporary target on PYTHONPATH, as site-packages would hold it) and driven through vecu's
commands in subprocesses: it appears in `vecu plugins`, runs in `vecu run` with its own
parameters, is scored by `vecu replay`, its sensor is faulted by a scenario (seen on the bus),
and vecu's A2L lists its calibration. Nothing of it is named inside vecu."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import can
import pytest

from vecu.codec import DbcCodec

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "vecu-oil-temperature"


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    work = tmp_path_factory.mktemp("example-plugin")
    shutil.copytree(EXAMPLE, work / "src", ignore=shutil.ignore_patterns("build", "*.egg-info"))
    target = work / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                    "--no-build-isolation", "--target", str(target), str(work / "src")],
                   check=True, timeout=300, capture_output=True)
    return target


def _vecu(site: Path, *argv: str, python: str | None = None
          ) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "VECU_KERNELS": "python",
           "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)])}
    cmd = ["-c", python] if python is not None else ["-m", "vecu"]
    done = subprocess.run([sys.executable, *cmd, *argv], capture_output=True, text=True,
                          env=env, cwd=site.parent, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def test_nothing_of_the_example_is_named_inside_vecu():
    for path in (ROOT / "vecu").rglob("*"):
        if path.is_file() and path.suffix in (".py", ".dbc", ".toml"):
            text = path.read_text(errors="replace")
            assert "oil_temperature" not in text and "OIL_" not in text, path


@pytest.mark.slow
def test_the_installed_example_runs_in_every_command(site, tmp_path):
    listed = json.loads(_vecu(site, "plugins", "--json").stdout)
    assert [(p["name"], p["package"], p["version"], p["error"]) for p in listed] == [
        ("oil_temperature", "vecu-oil-temperature", "0.1.0", None)]

    params = _vecu(site, "params", "ecu.oil_temperature").stdout
    assert "ecu.oil_temperature.model.tau_s" in params and "degC" in params

    log, summary = tmp_path / "run.blf", tmp_path / "run.json"
    out = _vecu(site, "run", "--duration", "1.5", "--log", str(log), "--summary", str(summary),
                "--set", "ecu.oil_temperature.r_degc2=0.3").stdout
    assert "oil temperature: estimate RMS error" in out
    oil = json.loads(summary.read_text())["oil_temperature"]
    assert oil["estimates_sent"] == 15
    assert oil["temp_error_degc"]["rms"] < 0.5  # below the sensor's 0.5 degC noise
    assert json.loads(summary.read_text())["config"]["params"] == {
        "ecu.oil_temperature.r_degc2": 0.3}

    replayed = _vecu(site, "replay", str(log), "--no-progress", "--summary",
                     str(tmp_path / "replay.json")).stdout
    assert "score oil_temperature" in replayed
    score = json.loads((tmp_path / "replay.json").read_text())
    assert "oil_temperature" in json.dumps(score["score"])

    a2l = _vecu(site, "a2l").stdout
    block = a2l.split("CHARACTERISTIC ecu.oil_temperature.r_degc2 ")[1].split("/end")[0]
    assert "READ_ONLY" not in block  # live: the function takes its subtree mid-run
    assert "MEASUREMENT oil_temperature.estimate_degc" in a2l


@pytest.mark.slow
def test_a_scenario_stops_the_plugins_sensor_and_the_bus_shows_the_estimate_degrade(site,
                                                                                   tmp_path):
    scenario = tmp_path / "oil.toml"
    scenario.write_text('duration_s = 2.0\n[[faults]]\ntarget = "OIL_Sensor"\n'
                        'kind = "frames_stop"\nstart_s = 1.0\n')
    log = tmp_path / "oil.blf"
    _vecu(site, str(scenario), str(log), python=(  # the scenario's run, recorded
        "import sys, dataclasses\n"
        "from vecu.runner import run\n"
        "from vecu.scenario.loader import load_scenario\n"
        "config = load_scenario(sys.argv[1]).config\n"
        "run(dataclasses.replace(config, log_path=sys.argv[2]))\n"))
    db = DbcCodec([EXAMPLE / "src" / "vecu_oil_temperature" / "oil.dbc"])
    est, sensor = db["OIL_Estimate"], db["OIL_Sensor"]
    frames = [(m.timestamp, m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(log))]
    assert max(t for t, i, _ in frames if i == sensor.frame_id) < 1.0  # the sensor stopped
    validity = [(t, est.decode(d)["OIL_Validity"]) for t, i, d in frames if i == est.frame_id]
    assert all(v == 1 for t, v in validity if t < 1.0)
    assert all(v == 2 for t, v in validity if t > 1.3)  # degraded after 3 silent periods
