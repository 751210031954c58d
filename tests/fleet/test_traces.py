"""One fleet trace at a time, in this process (the task a Dask worker runs): traces nobody here
wrote (python-can's and cantools' test logs, the OxTS trace on cantools' vehicle.dbc through its
signal map), the shipped reference traces diffed against their own recording and judged by
scenario criteria, and bad DIFF / criteria files."""

from __future__ import annotations

import json
from pathlib import Path

import can
import cantools
import pytest

from vecu.codec import builtin_dbc_path
from vecu.errors import BadArgumentError, BadFileError
from vecu.fleet.criteria import load_trace_criteria
from vecu.fleet.diff import DiffSpec, load_diff_spec
from vecu.fleet.task import FleetConfig, outputs, replay_trace
from vecu.fleet.traces import expand, trace_names
from vecu.replay.engine import ReplayConfig
from vecu.replay.reference import golden_path, references

THIRDPARTY = Path(__file__).resolve().parents[3] / "shared" / "thirdparty"
TRACES = Path(__file__).resolve().parents[2] / "traces"
LOGS = sorted((THIRDPARTY / "logs").glob("pythoncan_*")) if THIRDPARTY.is_dir() else []
needs_thirdparty = pytest.mark.skipif(not LOGS, reason="../shared/thirdparty not present")


@needs_thirdparty
def test_python_can_logs_diff_only_what_they_recorded_and_a_candump_is_an_error_row(tmp_path):
    """python-can's test logs: every frame read; the diff pairs exactly the frames the log holds
    of the ECU's messages (cantools' own reading of vecu.dbc says which), "none" without any."""
    db = cantools.database.load_file(str(builtin_dbc_path()))
    ecu = {m.frame_id: m.name for m in db.messages if "VECU" in m.senders}
    fleet = FleetConfig(ReplayConfig(trace=""), "log", DiffSpec())
    names = trace_names([str(p) for p in LOGS])
    kinds = set()
    for log, name in zip(LOGS, names):
        frames = [m for m in can.LogReader(str(log))
                  if not m.is_error_frame and not m.is_remote_frame]
        row = replay_trace(fleet, str(log), name, str(tmp_path))
        assert row["status"] != "error", (log.name, row["error"])
        assert row["frames_read"] == sum(1 for _ in can.LogReader(str(log)))
        recorded = {}
        for m in frames:
            if m.arbitration_id in ecu and not m.is_extended_id:
                recorded[ecu[m.arbitration_id]] = recorded.get(ecu[m.arbitration_id], 0) + 1
        if not recorded:
            assert row["diff"] == "none" and row["verdict"] == "none" and row["status"] == "ok"
        else:  # a foreign frame on one of the ECU's IDs: compared, and unlike the replay
            detail = json.loads(outputs(tmp_path, name, None)["diff"].read_text())
            assert {k: v["recorded"] for k, v in detail["messages"].items() if v["recorded"]} \
                == recorded
            assert row["diff"] == "fail" and row["status"] == "fail"
        kinds.add(row["diff"])
        assert outputs(tmp_path, name, "log")["summary"].is_file()
    assert kinds == {"none", "fail"}  # both cases occur among python-can's logs
    # cantools' fixture: a suffix python-can does not read, named in the trace's error row
    candump = THIRDPARTY / "logs" / "cantools_test_decode_log_format.candump"
    row = replay_trace(fleet, str(candump), "candump", str(tmp_path))
    assert row["status"] == "error" and row["verdict"] == "error"
    assert str(candump) in row["error"]


def test_oxts_trace_through_its_map_gives_its_golden_output_and_truth_criteria(tmp_path):
    ref = next(r for r in references() if r.signal_map)
    crit = tmp_path / "crit.toml"
    # no steering-wheel sensor in this trace: its monitor times out and confirms its DTC with no
    # fault event, which `no_false_dtc` would count
    crit.write_text('[criteria]\nno_false_dtc = false\n[truth]\n'
                    '"speed.speed_error_kmh" = { rms = 0.1 }\n'
                    '"steering.side_slip_error_deg" = { rms = 0.001 }\n')
    fleet = FleetConfig(ReplayConfig(trace="", dbc=(str(TRACES / ref.dbc[0]),),
                                     signal_map=str(TRACES / ref.signal_map)),
                        "log", DiffSpec(), load_trace_criteria(str(crit)))
    row = replay_trace(fleet, str(TRACES / ref.name), "oxts", str(tmp_path))
    paths = outputs(tmp_path, "oxts", "log")
    assert paths["out"].read_bytes() == golden_path(TRACES, ref).read_bytes()
    assert row["diff"] == "none"  # the OxTS logger recorded no ECU
    results = {c["name"]: c for c in json.loads(paths["criteria"].read_text())}
    assert results["speed.speed_error_kmh: rms error against truth"]["passed"]
    slip = results["steering.side_slip_error_deg: rms error against truth"]
    assert not slip["passed"] and float(slip["measured"]) > 0.001  # 0.0335 deg in this trace
    assert row["status"] == "fail" and row["criteria_failed"] == (
        "steering.side_slip_error_deg: rms error against truth")


CRITERIA = """[criteria]
no_false_dtc = true
[criteria.tps]
detect_within_ms = 20
detected_as = ["range_low"]
dtc = "confirmed"
[criteria.wheel]
not_detected = true
[truth]
"throttle.broadcast_error_deg" = { rms = 6.0 }
"""


def test_reference_trace_meets_its_criteria(tmp_path):
    """drive_tps_dead.blf: recorded by vecu run, TPS dead (0 V) at 1.5 s; its FI_Event gives the
    fault time, the ECU's TPS status the detection. (Not diffed: its ECU frames were recorded by
    an older vecu, before the validity signals and ECU_Diag; tests/fleet/test_fleet.py diffs
    fresh recordings.)"""
    ref = next(r for r in references() if r.name == "drive_tps_dead.blf")
    crit = tmp_path / "crit.toml"
    crit.write_text(CRITERIA)
    fleet = FleetConfig(ReplayConfig(trace=""), "log", None, load_trace_criteria(str(crit)))
    row = replay_trace(fleet, str(TRACES / ref.name), "tps_dead", str(tmp_path))
    paths = outputs(tmp_path, "tps_dead", "log")
    assert paths["out"].read_bytes() == golden_path(TRACES, ref).read_bytes()
    assert (row["status"], row["verdict"], row["criteria_failed"]) == ("ok", "pass", ""), row
    results = {c["name"]: c for c in json.loads(paths["criteria"].read_text())}
    latency = results["tps: detection latency"]["measured"]
    assert float(latency.split()[0]) <= 20 and "range_low" in latency
    assert results["tps: final DTC state"]["measured"] == "confirmed"
    # the same trace judged against a wrong expectation fails on exactly that criterion
    crit.write_text(CRITERIA.replace('detected_as = ["range_low"]', 'detected_as = ["stuck"]'))
    fleet = FleetConfig(ReplayConfig(trace=""), None, None, load_trace_criteria(str(crit)))
    row = replay_trace(fleet, str(TRACES / ref.name), "tps_dead2", str(tmp_path))
    assert row["status"] == "fail" and row["criteria_failed"] == "tps: detected as"


@pytest.mark.parametrize(("text", "problem"), [
    ("lsb = -1\n", "lsb"),
    ("max_share = 2\n", "max_share"),
    ("colour = 1\n", "unknown key 'colour'"),
    ('[tolerance]\n"THR_Angle" = "wide"\n', "tolerance.THR_Angle"),
])
def test_a_bad_diff_file_is_one_error_naming_the_key(tmp_path, text, problem):
    path = tmp_path / "diff.toml"
    path.write_text(text)
    with pytest.raises(BadFileError, match=problem) as err:
        load_diff_spec(str(path))
    assert str(path) in str(err.value)


@pytest.mark.parametrize(("text", "problem"), [
    ("[criteria.tps]\nfallback_within_ms = 5\n", "fallback_within_ms"),
    ("[criteria.tps]\ndetect_within = 5\n", "detect_within"),
    ('[truth]\n"speed.x" = { mean = 1 }\n', "truth.speed.x"),
    ("[plant]\nx = 1\n", "plant"),
])
def test_a_bad_criteria_file_is_one_error_naming_the_key(tmp_path, text, problem):
    path = tmp_path / "crit.toml"
    path.write_text(text)
    with pytest.raises(BadFileError, match=problem):
        load_trace_criteria(str(path))


def test_tolerances_by_signal_and_message(tmp_path):
    path = tmp_path / "diff.toml"
    path.write_text('lsb = 2\nignore = ["ECU_Status"]\n[tolerance]\n'
                    '"ECU_SpeedEstimate.SPD_VehSpeed" = 0.5\n"THR_Angle" = 0.2\n')
    spec = load_diff_spec(str(path))
    assert spec.tolerance_of("ECU_SpeedEstimate", "SPD_VehSpeed", 0.01) == 0.5
    assert spec.tolerance_of("ECU_ThrottleEstimate", "THR_Angle", 0.01) == 0.2
    assert spec.tolerance_of("ECU_SpeedEstimate", "SPD_VehAccel", 0.001) == 0.002
    assert spec.ignored("ECU_Status") and not spec.ignored("ECU_Diag")


def test_traces_from_directories_and_globs_each_once_with_unique_names(tmp_path):
    (tmp_path / "day1").mkdir()
    (tmp_path / "day2").mkdir()
    for p in ("day1/drive.blf", "day2/drive.blf", "day2/b.log.gz", "day2/notes.txt"):
        (tmp_path / p).write_bytes(b"")
    found = expand([str(tmp_path / "day2"), str(tmp_path / "day*" / "*.blf")])
    assert found == [str(tmp_path / "day2" / "b.log.gz"), str(tmp_path / "day2" / "drive.blf"),
                     str(tmp_path / "day1" / "drive.blf")]
    assert trace_names(found) == ["day2_b.log.gz", "day2_drive.blf", "day1_drive.blf"]
    with pytest.raises(BadArgumentError, match="matches no file"):
        expand([str(tmp_path / "none*.blf")])
