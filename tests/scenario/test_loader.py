"""Scenario loader: settings the run cannot honour are refused before the run, one line naming
the file and the key (issue 14 item 3); value faults on counters are accepted (they wrap)."""

from __future__ import annotations

import pytest

from vecu.scenario.batch import run_scenario
from vecu.scenario.loader import ScenarioError, load_scenario


@pytest.mark.parametrize("text,key,needle", [
    ("[ecu.tps]\ndtc_heal_ms = 1e308\n", "ecu.tps.dtc_heal_ms", "<= 1e+10"),
    ("[ecu.swa]\nheal_ms = 1e12\n", "ecu.swa.heal_ms", "<= 1e+10"),
    ("[ecu.wheel]\nplaus_debounce = 9000000000000000000\n", "ecu.wheel.plaus_debounce",
     "<= 1e+09"),
    ("[plant]\nnoise_scale = 1e300\n", "plant.noise_scale", "<= 1000"),
    ('[set]\n"plant.manifold.noise_scale" = 1e300\n', "set", "plant.manifold.noise_scale"),
    ('[set]\n"ecu.throttle.tps_monitor.dtc_heal_ms" = 1e308\n', "set", "<= 1e+10"),
])
def test_settings_the_run_cannot_honour_are_one_line_naming_the_key(tmp_path, text, key, needle):
    path = tmp_path / "bad.toml"
    path.write_text("duration_s = 0.5\n" + text)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(path)
    msg = str(exc.value)
    assert len(msg.splitlines()) == 1 and msg.startswith(f"{path}: key '{key}':"), msg
    assert needle in msg, msg


@pytest.mark.parametrize("target,kind,value", [
    ("ENG_Event.ENG_EventCounter", "offset", 300.0),
    ("ENG_Intake.ENG_IntakeCounter", "noise", 50.0),
    ("ENG_Event.ENG_Speed", "dead", None),
    ("ENG_Event.ENG_Speed", "gain", 0.0),
    ("ENG_Event.ENG_Speed", "offset", -1e4),
    ("ENG_Event.ENG_Speed", "noise", 1e4),
])
def test_issue_fault_sweep_cases_end_pass_or_fail_never_error(tmp_path, target, kind, value):
    """Issue 14 items 1 and 3: these declared faults ended in ERROR (ZeroDivisionError in the
    ECU, cantools OverflowError in the plant's re-encode)."""
    path = tmp_path / "fault.toml"
    path.write_text(f'duration_s = 0.4\n[plant]\nmanifold = true\n[[faults]]\ntarget = "{target}"\n'
                    f'kind = "{kind}"\nstart_s = 0.1\n'
                    + ("" if value is None else f"value = {value}\n"))
    outcome = run_scenario(load_scenario(path))
    assert outcome.error is None, outcome.error
    if kind != "offset" or "Counter" not in target:
        return
    assert outcome.passed  # a shifted counter is one gap, nothing the criteria judge


def test_a_file_that_is_not_utf8_is_one_line_naming_it(tmp_path, capsys):
    """Issue 14 item 9: was a UnicodeDecodeError traceback (TOML files are UTF-8)."""
    from vecu.cli import main

    path = tmp_path / "latin1.toml"
    path.write_bytes('duration_s = 0.5\ndescription = "Drosselklappe geöffnet"\n'.encode("latin-1"))
    with pytest.raises(ScenarioError) as exc:
        load_scenario(path)
    assert str(exc.value) == (f"{path}: not UTF-8 text (byte 0xf6 at offset 48, line 2): TOML "
                              f"files must be UTF-8")
    assert main(["scenario", "run", str(path)]) == 2
    assert capsys.readouterr().err == f"vecu: error: {exc.value}\n"


def test_a_scenario_shorter_than_one_tick_is_refused(tmp_path):
    """Issue 14 item 8: duration_s = 0.0004 ran no tick and passed."""
    path = tmp_path / "tiny.toml"
    path.write_text("duration_s = 0.0004\n")
    with pytest.raises(ScenarioError, match=r"key 'duration_s': must be in \[0.001, 86400\] s"):
        load_scenario(path)


@pytest.mark.parametrize(("step", "needle"), [
    ('at_s = 0.1\nrequest = "22 F1 9G"', "key 'uds[0].request': expected hex bytes"),
    ('at_s = 5.0\nrequest = "3E 00"', "key 'uds[0].at_s': 5 s is outside the run"),
    ('request = "3E 00"', "key 'uds[0].at_s': required key missing"),
    ('at_s = 0.1\nrequest = "22 F1 90 F1 8C F1 95 01"\nfunctional = true',
     "a functional request fits one frame"),
    ('at_s = 0.1\nrequest = "3E 00"\nexpect_nrc = 300', "key 'uds[0].expect_nrc'"),
])
def test_bad_uds_steps_are_one_line_naming_the_key(tmp_path, step, needle):
    """Issue 17: [[uds]] steps in a scenario file."""
    path = tmp_path / "bad.toml"
    path.write_text(f"duration_s = 1.0\n[[uds]]\n{step}\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert needle in str(err.value) and "\n" not in str(err.value)
