"""Scenario reports: a scenario's name becomes a safe file name for its plot (issue 14 item 9: a
name with '/' broke --report)."""

from __future__ import annotations

from pathlib import Path

import pytest

from vecu.cli import main
from vecu.scenario.report import plot_file_name

SHIPPED = sorted((Path(__file__).resolve().parents[2] / "vecu/data/scenarios").glob("*.toml"))


@pytest.mark.parametrize("name", ["tps_dead", "wheel-frames.dropout", "A1"])
def test_a_safe_name_keeps_its_file_name(name: str) -> None:
    assert plot_file_name(name) == f"{name}.png"


@pytest.mark.parametrize("name", ["a/b", "../../etc/x", "a\\b", "C:x", "", ".hidden", "a b",
                                  "x" * 300, "nul\0", "é"])
def test_an_unsafe_name_becomes_one_plain_file_name(name: str) -> None:
    file = plot_file_name(name)
    assert Path(file).name == file and not file.startswith(".") and len(file) <= 120
    assert set(file) <= set("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-")


def test_names_that_sanitise_alike_keep_apart() -> None:
    assert len({plot_file_name(n) for n in ("a/b", "a_b", "a:b", "a b")}) == 4


def test_report_of_a_scenario_named_with_a_slash(tmp_path: Path, capsys) -> None:
    scenario = tmp_path / "s.toml"
    scenario.write_text('name = "tps/dead ../x"\nduration_s = 0.3\n')
    report = tmp_path / "report"
    assert main(["scenario", "run", str(scenario), "--report", str(report), "--quiet"]) == 0
    assert "1/1 passed" in capsys.readouterr().out
    plots = [p.name for p in report.iterdir() if p.suffix == ".png"]
    assert plots == [plot_file_name("tps/dead ../x")]
    assert f'src="{plots[0]}"' in (report / "index.html").read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "s.toml"]


def test_dtc_histories_are_tables(tmp_path: Path, capsys) -> None:
    """Each sensor's DTC history in the report is a table of (time, state), not a Python repr."""
    scenario = tmp_path / "s.toml"
    scenario.write_text('name = "dtc"\nduration_s = 0.8\n[[faults]]\ntarget = "tps"\n'
                        'kind = "dead"\nstart_s = 0.2\n')
    report = tmp_path / "report"
    assert main(["scenario", "run", str(scenario), "--report", str(report), "--quiet"]) == 0
    page = (report / "index.html").read_text()
    assert "<th>time</th><th>DTC state</th>" in page
    assert "<td>confirmed</td>" in page and "('confirmed'" not in page
    assert "[(" not in page
