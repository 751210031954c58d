"""[[xcp]] steps in scenarios: the shipped one passes, a wrong expectation fails, bad steps are
one-line errors naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from vecu.errors import ConfigError
from vecu.runner import run
from vecu.scenario.criteria import evaluate
from vecu.scenario.loader import ScenarioError, load_scenario

SHIPPED = Path(__file__).resolve().parents[2] / "vecu" / "data" / "scenarios" / "xcp_tps_debounce.toml"


def _variant(tmp_path: Path, old: str, new: str) -> Path:
    p = tmp_path / "s.toml"
    text = SHIPPED.read_text()
    assert old in text
    p.write_text(text.replace(old, new, 1))
    return p


def test_the_shipped_xcp_scenario_passes_and_calibrates():
    sc = load_scenario(SHIPPED)
    result = run(sc.config)
    steps = result.summary["xcp_steps"]
    assert len(steps) == 8 and all(s["passed"] for s in steps), steps
    assert result.summary["xcp"]["calibrations_taken"][0][1:] == [
        "ecu.throttle.tps_monitor.plaus_debounce", 20]
    assert result.summary["xcp"]["refused_writes"] == 1


def test_a_wrong_expectation_fails(tmp_path):
    sc = load_scenario(_variant(tmp_path, "expect = 20\n", "expect = 21\n"))
    result = run(sc.config)
    failed = [s for s in result.summary["xcp_steps"] if not s["passed"]]
    assert [s["got"] for s in failed] == ["20"]


@pytest.mark.parametrize("old, new, message", [
    ('read = "monitor.tps.status"', 'read = "monitor.tps.nope"', "no characteristic or measurement"),
])
def test_an_unknown_name_is_a_user_error(tmp_path, old, new, message):
    sc = load_scenario(_variant(tmp_path, old, new))
    with pytest.raises(ConfigError, match=message):
        run(sc.config)


@pytest.mark.parametrize("old, new, key", [
    ("at_s = 1.3\n", "at_s = 9.0\n", "xcp[7].at_s"),
    ('expect_error = "ERR_OUT_OF_RANGE"', 'expect_error = "out of range"', "xcp[4].expect_error"),
    ("value = 20\n", "valeu = 20\n", "xcp[2]"),
])
def test_bad_steps_name_the_key(tmp_path, old, new, key):
    with pytest.raises(ScenarioError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load_scenario(_variant(tmp_path, old, new))


def test_criteria_list_the_steps():
    sc = load_scenario(SHIPPED)
    names = [c.name for c in evaluate(sc, run(sc.config))]
    assert any(n.startswith("xcp[2] at 0.3 s: write ecu.throttle.tps_monitor.plaus_debounce=20")
               for n in names)
