"""`vecu excite throttle`, `vecu identify throttle`, `--params` on run / replay (issue 18)."""

from __future__ import annotations

import pytest
import tomllib

from vecu.cli import main


def test_excite_identify_and_run_on_the_calibration(tmp_path, capsys) -> None:
    trace, params, fig = tmp_path / "ex.blf", tmp_path / "p.toml", tmp_path / "fig2.png"
    assert main(["excite", "throttle", "--duration", "8", "--seed", "3", "--log", str(trace),
                 "--set", "plant.throttle.noise_scale=0.3",
                 "--set", "plant.throttle.model.mode3.b=0.05"]) == 0
    assert main(["identify", "throttle", str(trace), "--out", str(params), "--plot", str(fig)]) == 0
    out = capsys.readouterr().out
    assert "mode3.b" in out and "95 % CI" in out and "one-step residuals" in out
    assert "note: modes 1-2 intervals are indicative only on a 8 s trace" in out  # < 180 s
    sets = tomllib.loads(params.read_text())["set"]
    assert 0.045 < sets["ecu.throttle.model.mode3.b"] < 0.055
    assert fig.stat().st_size > 10_000
    assert main(["replay", str(trace), "--params", str(params), "--quiet"]) == 0
    assert main(["run", "--duration", "0.2", "--params", str(params), "--quiet"]) == 0


@pytest.mark.parametrize(("text", "problem"), [
    ('[set]\n"ecu.throttle.model.mode3.bb" = 1\n', "[set] key 'ecu.throttle.model.mode3.bb'"),
    ("[other]\nx = 1\n", "expected a [set] table"),
    ('[set]\n"plant.throttle.noise_scale" = 1\n', "takes ecu.* parameters only"),
])
def test_a_bad_params_file_is_one_line_naming_it(tmp_path, capsys, text, problem) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    trace = tmp_path / "t.log"
    trace.write_text("(0.000000) can0 100#00\n")
    assert main(["replay", str(trace), "--params", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"vecu: error: {bad}: ") and problem in err and "\n" not in err


def test_a_trace_that_cannot_support_a_fit_is_one_line(tmp_path, capsys) -> None:
    short = tmp_path / "short.log"
    assert main(["excite", "throttle", "--duration", "1", "--log", str(short), "--quiet"]) == 0
    assert main(["identify", "throttle", str(short)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"vecu: error: {short}: too short") and "\n" not in err
    other = tmp_path / "other.log"
    other.write_text("(0.000000) vcan0 123#00\n(0.001000) vcan0 123#00\n")
    assert main(["identify", "throttle", str(other), "--out", str(tmp_path / "p.json")]) == 2
    assert "--out" in capsys.readouterr().err
    assert main(["identify", "throttle", str(other)]) == 2
    assert "0 samples with motor voltage, wattmeter power and TPS angle" in capsys.readouterr().err
