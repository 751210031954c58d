"""A scenario's [[diag_faults]]: the ECU of a simulated run commits the fault (here 0x78 three
times, 200 ms apart, before the answer) and the scenario's tester waits through it, as ISO
14229-2 asks (each 0x78 restarts its wait with P2*); bad entries are one line naming the key."""

from __future__ import annotations

import pytest

from vecu.scenario.batch import run_scenario
from vecu.scenario.loader import ScenarioError, load_scenario

SCENARIO = """
duration_s = 1.5
[plant]
speed = false
steering = false
manifold = false
[[diag_faults]]
name = "pending"
value = 3
at_s = 0.2
[[uds]]
at_s = 0.5
request = "22 F1 90"
expect = "62 F1 90"
"""


def test_the_ecu_commits_the_fault_in_a_scenario(tmp_path):
    path = tmp_path / "pending.toml"
    path.write_text(SCENARIO)
    scenario = load_scenario(path)
    assert [str(s) for s in scenario.config.diag_faults] == ["pending=3@0.2"]
    out = run_scenario(scenario)
    assert out.passed, out
    step = next(c for c in out.criteria if "uds" in c.name.lower())
    assert step.passed and "62 f1 90" in step.measured
    latency_ms = float(step.measured.rsplit("after ", 1)[1].split()[0])
    assert 600 <= latency_ms <= 605  # 3 x 0x78 200 ms apart, then the answer: the fault happened


@pytest.mark.parametrize("entry,needle", [
    ('name = "pendng"', "unknown diagnostic fault 'pendng' (known: pending,"),
    ('name = "pending"\nvalue = 500', "N must be an integer 1..100, got 500"),
    ('name = "pending"\nat_s = 9.0', "key 'diag_faults[0].at_s'"),
])
def test_bad_diag_faults_are_one_line(tmp_path, entry, needle):
    path = tmp_path / "bad.toml"
    path.write_text(f"duration_s = 1.0\n[[diag_faults]]\n{entry}\n")
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert needle in str(err.value) and "\n" not in str(err.value)
