"""An FMU nobody here wrote (the Modelica Association's Reference FMUs, FMI 2.0 and 3.0) as an
ECU function: what appears on the bus, decoded from the trace, on run, replay and a scenario."""

from __future__ import annotations

import zipfile
from pathlib import Path

import can
import pytest

from vecu.cli import main as cli_main
from vecu.codec import DbcCodec, builtin_dbc_path

pytest.importorskip("fmpy")

HERE = Path(__file__).parent
OUT_DBC = HERE / "fmu_out.dbc"
QUICK = ["--set", "ecu.xcp.enabled=false"]


@pytest.fixture
def fmus(thirdparty: Path) -> Path:
    return thirdparty / "fmu"


def _db() -> DbcCodec:
    return DbcCodec([OUT_DBC, builtin_dbc_path()], strict=False)


def _frames(log: Path, name: str) -> list[tuple[float, dict[str, float], bytes]]:
    db = _db()
    fc = db[name]
    return [(round(m.timestamp, 6), fc.decode(m.data), bytes(m.data))
            for m in can.LogReader(str(log)) if m.arbitration_id == fc.frame_id]


@pytest.mark.parametrize("fmi", ["fmi2", "fmi3"])
def test_feedthrough_sends_its_input_signal_back_unchanged(fmus, fmi, tmp_path, capsys):
    log, out = tmp_path / "run.blf", tmp_path / "replay.blf"
    fmu, fmu_map = str(fmus / fmi / "Feedthrough.fmu"), str(HERE / "feedthrough.toml")
    assert cli_main(["run", "--duration", "1", "--kill-tps-at", "none", "--log", str(log),
                     "--fmu", fmu, "--fmu-map", fmu_map, *QUICK]) == 0
    assert "fmu Feedthrough: 99 steps, 100 frames sent, 0 errors, valid" in capsys.readouterr().out
    volts = [(t, v["ETB_Voltage"]) for t, v, _ in _frames(log, "ETB_Wattmeter")]
    outs = _frames(log, "FMU_Out")
    assert len(outs) == 100 and [t for t, _, _ in outs] == [i / 100 for i in range(100)]
    for t, values, _ in outs[1:]:  # the voltage the ECU received in the same tick
        latest = [v for tv, v in volts if tv <= t][-1]
        assert values["FMU_Value"] == pytest.approx(latest, abs=1e-9)
    assert outs[0][1]["FMU_Value"] == 0.0  # the FMU's start value before its first step
    assert len({v["FMU_Value"] for _, v, _ in outs} - {0.0}) >= 2  # the voltage steps
    # the ECU alone on the recorded trace sends the same frames, bit for bit
    assert cli_main(["replay", str(log), "--out", str(out), "--fmu", fmu, "--fmu-map", fmu_map,
                     "--no-progress"]) == 0
    assert [d for _, _, d in _frames(out, "FMU_Out")] == [d for _, _, d in outs]


@pytest.mark.parametrize("fmi", ["fmi2", "fmi3"])
def test_a_calibrated_dahlquist_k_changes_the_output_as_its_equation_says(fmus, fmi, tmp_path):
    """Dahlquist: x' = -k x, x(0) = 1, one forward-Euler step of h = 0.1 s per communication
    step (the Reference FMU's fixed step): x_n = (1 - k h)^n, on run (k = 2) and on the replay of
    that run's trace (k = 3)."""
    log, out = tmp_path / "run.blf", tmp_path / "replay.blf"
    fmu, fmu_map = str(fmus / fmi / "Dahlquist.fmu"), str(HERE / "dahlquist.toml")
    assert cli_main(["run", "--duration", "1", "--kill-tps-at", "none", "--log", str(log),
                     "--fmu", fmu, "--fmu-map", fmu_map, "--set", "ecu.fmu.Dahlquist.k=2",
                     "--quiet", *QUICK]) == 0
    assert cli_main(["replay", str(log), "--out", str(out), "--fmu", fmu, "--fmu-map", fmu_map,
                     "--set", "ecu.fmu.Dahlquist.k=3", "--quiet", "--no-progress"]) == 0
    fc = _db()["DQ_Out"]
    for path, k in ((log, 2.0), (out, 3.0)):
        frames = _frames(path, "DQ_Out")
        assert [t for t, _, _ in frames] == [n / 10 for n in range(10)]
        for n, (_, values, data) in enumerate(frames):
            assert values["DQ_X"] == pytest.approx((1 - k * 0.1) ** n, abs=2e-6)
            assert values["DQ_AliveCounter"] == n % 15  # E2E: vecu's layout, counter and CRC
            assert fc.crc_ok(data)


def _model_exchange_only(src: Path, dst: Path) -> Path:
    with zipfile.ZipFile(src) as zi, zipfile.ZipFile(dst, "w") as zo:
        for item in zi.infolist():
            data = zi.read(item)
            if item.filename == "modelDescription.xml":
                text = data.decode()
                start = text.index("<CoSimulation")
                end = text.index(">", text.index("</CoSimulation>") if "</CoSimulation>" in text
                                 else start) + 1
                data = (text[:start] + text[end:]).encode()
            zo.writestr(item, data)
    return dst


@pytest.mark.parametrize("inputs, problem", [
    ('Float64_nope = "ETB_Wattmeter.ETB_Voltage"', "no variable 'Float64_nope' in the FMU"),
    ('Int32_input = "ETB_Wattmeter.ETB_Voltage"', "does not fit ETB_Wattmeter.ETB_Voltage"),
    ('Float64_continuous_input = "ETB_Wattmeter.Nope"', "has no signal 'Nope'"),
    ('Float64_continuous_output = "ETB_Wattmeter.ETB_Voltage"', "not an input"),
])
def test_a_bad_map_is_one_line_before_anything_runs(fmus, tmp_path, capsys, inputs, problem):
    fmu_map = tmp_path / "map.toml"
    fmu_map.write_text(f'[fmu]\nstep_ms = 10\ndbc = "{OUT_DBC}"\n[inputs]\n{inputs}\n'
                       '[outputs]\nFloat64_continuous_output = "FMU_Out.FMU_Value"\n')
    log = tmp_path / "run.blf"
    assert cli_main(["run", "--fmu", str(fmus / "fmi3" / "Feedthrough.fmu"), "--fmu-map",
                     str(fmu_map), "--log", str(log)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"vecu: error: {fmu_map}: [inputs]")
    assert problem in err[0] and not log.exists()


def test_an_fmu_without_co_simulation_is_refused(fmus, tmp_path, capsys):
    fmu = _model_exchange_only(fmus / "fmi2" / "Feedthrough.fmu", tmp_path / "me.fmu")
    assert cli_main(["run", "--fmu", str(fmu), "--fmu-map", str(HERE / "feedthrough.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "without co-simulation" in err[0] and str(fmu) in err[0]


def test_a_failing_fmu_turns_invalid_and_the_ecu_runs_on(fmus, tmp_path, capsys):
    """Reference FMU `Resource` without its resource file: fmi2ExitInitializationMode returns
    fmi2Error; its function is invalid, sends nothing, the throttle keeps broadcasting."""
    broken = tmp_path / "Resource.fmu"
    with zipfile.ZipFile(fmus / "fmi2" / "Resource.fmu") as zi, zipfile.ZipFile(broken, "w") as zo:
        for item in zi.infolist():
            if item.filename != "resources/y.txt":
                zo.writestr(item, zi.read(item))
    fmu_map = tmp_path / "map.toml"
    fmu_map.write_text(f'[fmu]\nstep_ms = 10\ndbc = "{OUT_DBC}"\n'
                       '[outputs]\ny = "FMU_Out.FMU_Count"\n')
    log = tmp_path / "run.blf"
    assert cli_main(["run", "--duration", "0.3", "--fmu", str(broken), "--fmu-map", str(fmu_map),
                     "--log", str(log), *QUICK]) == 0
    assert "fmu Resource: 0 steps, 0 frames sent, 1 errors, INVALID" in capsys.readouterr().out
    assert _frames(log, "FMU_Out") == []
    assert len(_frames(log, "ECU_ThrottleEstimate")) == 300  # the ECU runs on
    # the intact FMU sends its resource's first value
    assert cli_main(["run", "--duration", "0.3", "--fmu", str(fmus / "fmi2" / "Resource.fmu"),
                     "--fmu-map", str(fmu_map), "--log", str(log), *QUICK]) == 0
    assert len(_frames(log, "FMU_Out")) == 30


def test_parameters_are_in_the_tree_the_a2l_and_a_scenario(fmus, tmp_path, capsys):
    fmu, fmu_map = str(fmus / "fmi3" / "Feedthrough.fmu"), str(HERE / "feedthrough.toml")
    assert cli_main(["params", "ecu.fmu", "--fmu", fmu, "--fmu-map", fmu_map,
                     "--set", "ecu.fmu.Feedthrough.Float64_fixed_parameter=3"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert [r.split()[:2] for r in rows] == [
        ["ecu.fmu.Feedthrough.Float64_fixed_parameter", "3.0"],
        ["ecu.fmu.Feedthrough.Float64_tunable_parameter", "1.5"]]  # the map's start value
    assert cli_main(["a2l", "--fmu", fmu, "--fmu-map", fmu_map]) == 0
    a2l = capsys.readouterr().out
    block = {name: a2l.split(f"CHARACTERISTIC ecu.fmu.Feedthrough.{name} ")[1].split("/end")[0]
             for name in ("Float64_fixed_parameter", "Float64_tunable_parameter")}
    assert "READ_ONLY" in block["Float64_fixed_parameter"]  # fixed: set before initialisation
    assert "READ_ONLY" not in block["Float64_tunable_parameter"]  # tunable: calibratable
    assert "MEASUREMENT fmu.Feedthrough.Float64_continuous_output" in a2l
    # a timed calibration of the tunable one is taken; of the fixed one refused (one line)
    assert cli_main(["run", "--duration", "0.2", "--fmu", fmu, "--fmu-map", fmu_map, "--quiet",
                     "--set-at", "0.1:ecu.fmu.Feedthrough.Float64_tunable_parameter=4"]) == 0
    assert cli_main(["run", "--duration", "0.2", "--fmu", fmu, "--fmu-map", fmu_map, "--quiet",
                     "--set-at", "0.1:ecu.fmu.Feedthrough.Float64_fixed_parameter=4"]) == 2
    assert "Float64_fixed_parameter" in capsys.readouterr().err

    from vecu.runner import run
    from vecu.scenario.loader import load_scenario

    scenario = tmp_path / "fmu.toml"
    scenario.write_text(f'duration_s = 0.2\n[fmu]\nfile = "{fmu}"\nstep_ms = 20\n'
                        f'dbc = "{OUT_DBC}"\n[fmu.inputs]\n'
                        'Float64_continuous_input = "ETB_Wattmeter.ETB_Voltage"\n'
                        '[fmu.outputs]\nFloat64_continuous_output = "FMU_Out.FMU_Value"\n'
                        '[set]\n"ecu.fmu.Feedthrough.Float64_tunable_parameter" = 2.5\n'
                        # a tester reads its validity and its second parameter (micro-units)
                        '[[uds]]\nat_s = 0.1\nrequest = "22 06 0F"\nexpect = "62 06 0F 01"\n'
                        '[[uds]]\nat_s = 0.15\nrequest = "22 06 11"\n'
                        'expect = "62 06 11 00 26 25 A0"\n')
    config = load_scenario(scenario).config
    assert config.params.ecu.fmu.Feedthrough.Float64_tunable_parameter == 2.5
    report = run(config).report
    section = report.functions["fmu"]
    assert (section.steps, section.frames_sent, section.valid_at_end) == (9, 20, True)
    assert report.uds_steps is not None and [s["passed"] for s in report.uds_steps] == [True,
                                                                                         True]


def test_a_configuration_with_an_fmu_pickles_for_worker_processes(fmus):
    import pickle

    from vecu.config import RunConfig
    from vecu.fmu.binding import load_binding

    binding = load_binding(str(fmus / "fmi2" / "Dahlquist.fmu"), str(HERE / "dahlquist.toml"))
    config = RunConfig().with_fmu(binding).with_params({"ecu.fmu.Dahlquist.k": 2.5})
    copy = pickle.loads(pickle.dumps(config))
    assert copy == config and copy.params.ecu.fmu.Dahlquist.k == 2.5


def test_an_output_database_that_takes_an_id_on_the_bus_is_refused(fmus, tmp_path, capsys):
    clash = tmp_path / "clash.dbc"
    clash.write_text(OUT_DBC.read_text().replace("1424", "512"))  # ECU_ThrottleEstimate's ID
    fmu_map = tmp_path / "map.toml"
    fmu_map.write_text(f'[fmu]\nstep_ms = 10\ndbc = "{clash}"\n'
                       '[outputs]\nFloat64_continuous_output = "FMU_Out.FMU_Value"\n')
    assert cli_main(["run", "--fmu", str(fmus / "fmi3" / "Feedthrough.fmu"), "--fmu-map",
                     str(fmu_map)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [(f"vecu: error: {clash}: FMU_Out: CAN ID 0x200 is ECU_ThrottleEstimate's on "
                   "the bus already: give it another ID")]
