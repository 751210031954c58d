"""Scenario files: validation, the shipped set passes, a broken ECU fails, reports for CI."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import pytest

from vecu.cli import main as cli_main
from vecu.runner import RunConfig, run
from vecu.scenario.batch import run_scenario, run_scenarios
from vecu.scenario.loader import ScenarioError, load_scenario
from vecu.scenario.report import write_html, write_junit

REPO = Path(__file__).resolve().parents[2]
SHIPPED = sorted((REPO / "vecu" / "data" / "scenarios").glob("*.toml"))

BASE = """duration_s = 2.0
[[faults]]
target = "tps"
kind = "dead"
start_s = 1.0
"""


@pytest.mark.parametrize("text,key,needle", [
    (BASE + "bogus = 1\n", "faults[0].bogus", "unknown key"),
    ("duration_s = 2.0\ncolour = 'red'\n", "colour", "unknown key"),
    ("duration_s = 'long'\n", "duration_s", "expected a number, got a string"),
    ("duration_s = 2.0\n[plant]\nspeed = 1\n", "plant.speed", "expected true or false"),
    (BASE.replace("1.0\n", "5.0\n"), "faults[0].start_s", "outside the run"),
    (BASE + "end_s = 0.5\n", "faults[0].end_s", "not after start_s"),
    (BASE.replace('"dead"', '"melt"'), "faults[0].kind", "unknown fault kind"),
    (BASE.replace('"tps"', '"swa"'), "faults[0].target", "plant.steering = true"),
    (BASE.replace('"tps"', '"ESC_Motion"').replace('"dead"', '"bad_crc"'),
     "faults[0].target", "no E2E"),
    (BASE.replace('"dead"', '"gain"') + "value = 2.0\n", "faults[0].value", "G must be"),
    ("duration_s = 2.0\n[ecu.tps]\nplaus_sigma = 'x'\n", "ecu.tps.plaus_sigma", "a number"),
    ("duration_s = 2.0\n[criteria.tps]\ndtc = 'gone'\n", "criteria.tps.dtc", "expected one of"),
    ("seed = 1\n", "duration_s", "required key missing"),
])
def test_bad_scenario_is_one_line_naming_file_and_key(tmp_path, text, key, needle):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(path)
    msg = str(exc.value)
    assert len(msg.splitlines()) == 1 and msg.startswith(f"{path}: key '{key}':"), msg
    assert needle in msg


def test_toml_syntax_error_and_cli_exit_2(tmp_path, capsys):
    path = tmp_path / "broken.toml"
    path.write_text("duration_s = = 2\n")
    assert cli_main(["scenario", "run", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and "TOML" in err


def test_shipped_set_covers_the_issue_and_every_scenario_passes(tmp_path):
    assert len(SHIPPED) >= 10
    scenarios = [load_scenario(p) for p in SHIPPED]
    kinds = {(f.target, f.kind) for s in scenarios for f in s.config.faults}
    for needed in (("tps", "dead"), ("tps", "stuck"), ("tps", "frames_stop"),
                   ("tps", "short_supply"), ("swa", "stuck"), ("wheel", "dead"),
                   ("TPS_Sensor", "babble"), ("TPS_Sensor", "bad_crc")):
        assert needed in kinds
    outcomes = run_scenarios(scenarios, jobs=2, report_dir=str(tmp_path), stream=None)
    failed = {o.name: [(c.name, c.measured) for c in o.failures] or o.error
              for o in outcomes if not o.passed}
    assert not failed, failed
    # parallel == serial: same verdicts and measurements (runs are seeded and independent)
    serial = run_scenario(scenarios[0])
    assert [(c.name, c.measured) for c in serial.criteria] == \
        [(c.name, c.measured) for c in outcomes[0].criteria]
    junit = tmp_path / "j.xml"
    write_junit(outcomes, str(junit))
    root = ET.parse(junit).getroot()
    assert root.get("tests") == str(len(SHIPPED)) and root.get("failures") == "0"
    cases = root.findall(".//testcase")
    assert {c.get("name") for c in cases} == {s.name for s in scenarios}
    assert all(float(c.find("properties/property[@name='x_realtime']").get("value")) > 0
               for c in cases)
    index = Path(write_html(outcomes, str(tmp_path)))
    page = index.read_text()
    for s in scenarios:
        png = tmp_path / f"{s.name}.png"
        assert png.read_bytes()[:4] == b"\x89PNG" and f'src="{s.name}.png"' in page


def _disable(scenario, sensor):
    from vecu.scenario.loader import MONITOR_PATHS

    cfg = scenario.config.with_params({f"{MONITOR_PATHS[sensor]}.enabled": False})
    return replace(scenario, config=cfg)


def test_broken_ecu_detection_disabled_fails_the_right_scenarios(tmp_path):
    """TPS detection off: the TPS scenarios fail on detection, the SWA one still passes."""
    names = ("tps_dead", "tps_frames_stop", "wheel_dead", "swa_frames_stop")
    scen = {n: load_scenario(REPO / "vecu" / "data" / "scenarios" / f"{n}.toml") for n in names}
    broken = [_disable(scen["tps_dead"], "tps"), _disable(scen["tps_frames_stop"], "tps"),
              _disable(scen["wheel_dead"], "wheel"), _disable(scen["swa_frames_stop"], "tps")]
    outcomes = run_scenarios(broken, stream=None)
    verdict = {o.name: o for o in outcomes}
    for name in ("tps_dead", "tps_frames_stop", "wheel_dead"):
        failed = {c.name for c in verdict[name].failures}
        assert any("detection latency" in f for f in failed), (name, failed)
    assert verdict["wheel_dead"].failures and any(
        "error after fallback" in c.name for c in verdict["wheel_dead"].failures)
    assert verdict["swa_frames_stop"].passed  # only TPS detection was disabled
    junit = tmp_path / "broken.xml"
    write_junit(outcomes, str(junit))
    root = ET.parse(junit).getroot()
    assert root.get("tests") == "4" and root.get("failures") == "3"
    assert len(root.findall(".//failure")) == 3


def test_cli_exits_1_on_a_failing_criterion_and_writes_junit(tmp_path, capsys):
    path = tmp_path / "strict.toml"
    path.write_text((REPO / "vecu" / "data" / "scenarios" / "tps_stuck.toml").read_text()
                    .replace("detect_within_ms = 10", "detect_within_ms = 1"))
    junit = tmp_path / "out.xml"
    assert cli_main(["scenario", "run", str(path), "--junit", str(junit), "--quiet"]) == 1
    assert "0/1 passed" in capsys.readouterr().out
    failure = ET.parse(junit).getroot().find(".//failure")
    assert failure is not None and "detection latency" in failure.text


def test_wheel_dropout_coasts_on_the_accelerometer_and_heals():
    """ESC_Motion frames lost 1.0-2.0 s: timeout DTC, coast mode, wheel trusted again later."""
    sc = load_scenario(REPO / "vecu" / "data" / "scenarios" / "wheel_frames_dropout.toml")
    res = run(replace(sc.config, duration_s=3.0))
    wheel = res.summary["diagnostics"]["wheel"]
    assert wheel["first_fault_status"] == "timeout" and 1.0 <= wheel["first_fault_s"] < 1.1
    assert wheel["status"] == "ok" and wheel["dtc"] == "confirmed"  # healed status, DTC stored
    assert res.summary["speed"]["coast_steps"] > 250  # >= 0.5 s without the wheel
    s = res.series_of("speed")
    sel = (s.t_s >= 1.0) & (s.t_s < 2.5)
    assert abs(s.v_est[sel] - s.v_true[sel]).max() < 5.0  # km/h while coasting through braking


def test_no_false_dtc_in_60_s_fault_free_driving_default_thresholds():
    """The 1 h figure is measured by benchmarks/soak_no_false_dtc.toml; here 60 s, all three
    monitored sensors, production estimator, default thresholds."""
    res = run(RunConfig(duration_s=60.0, seed=8, kill_tps_at_s=None, manifold=False))
    diag = res.summary["diagnostics"]
    assert {name: d["confirmations"] for name, d in diag.items()} == \
        {"tps": 0, "swa": 0, "wheel": 0, "bus": 0}
