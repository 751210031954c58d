"""Replay robustness on files nobody here wrote: every python-can test log with every cantools
test DBC ends in a summary that accounts for every frame; the shipped reference traces replay to
their golden outputs, bit for bit; a third-party DBC drives the estimators through a signal map."""

from __future__ import annotations

from pathlib import Path

import can
import pytest

from vecu.codec import DbcCodec
from vecu.replay.engine import ReplayConfig, replay
from vecu.replay.reference import golden_path, references, replay_reference

THIRDPARTY = Path(__file__).resolve().parents[3] / "shared" / "thirdparty"
TRACES = Path(__file__).resolve().parents[2] / "traces"
LOGS = sorted((THIRDPARTY / "logs").glob("pythoncan_*")) if THIRDPARTY.is_dir() else []
DBCS = sorted((THIRDPARTY / "dbc").glob("*.dbc")) if THIRDPARTY.is_dir() else []
needs_thirdparty = pytest.mark.skipif(not LOGS, reason="../shared/thirdparty not present")


def _accounted(fr: dict) -> int:
    """Frames in exactly one bin: decoded, unknown, error, remote, rejected, ignored."""
    return (fr["decoded"] + fr["unknown_id"] + fr["error_frames"] + fr["remote_frames"]
            + fr["rejected"] + fr["ignored_known"])


@needs_thirdparty
@pytest.mark.parametrize("log", LOGS, ids=lambda p: p.name)
def test_every_log_with_every_dbc_ends_in_a_full_summary(log):
    expected = sum(1 for _ in can.LogReader(str(log)))
    for dbc in [None, *DBCS]:
        res = replay(ReplayConfig(trace=str(log), dbc=(str(dbc),) if dbc else (), progress=False))
        fr = res.summary["frames"]
        assert res.error is None, (dbc, res.error)
        assert fr["read"] == expected, dbc
        assert _accounted(fr) == expected, (dbc, fr)


@needs_thirdparty
def test_canoe_trace_decodes_with_a_matching_dbc_and_error_remote_fd_frames_are_binned():
    mixed = THIRDPARTY / "logs" / "pythoncan_logfile.asc"
    fr = replay(ReplayConfig(trace=str(mixed), progress=False)).summary["frames"]
    assert fr["error_frames"] == 4 and fr["remote_frames"] == 4 and fr["read"] == 20


@needs_thirdparty
def test_cantools_candump_fixture_decodes_like_cantools_until_pythoncan_stops():
    """cantools' log-format fixture: the frames python-can reads decode as cantools' expected
    output says (3 x SENSOR_SONARS ok, 0x064 wrong size); its bare 'ERROR' line stops python-can's
    reader, which replay reports as one line naming the file and the frame count."""
    log = THIRDPARTY / "logs" / "cantools_test_decode_log_format.candump"
    expected = (THIRDPARTY / "logs" / "cantools_test_decode_log_format.expected.txt").read_text()
    assert expected.count("SENSOR_SONARS(") == 3 and "Wrong data size" in expected
    res = replay(ReplayConfig(trace=str(log), fmt="log", progress=False,
                              dbc=(str(THIRDPARTY / "dbc" / "socialledge.dbc"),)))
    fr = res.summary["frames"]
    assert fr["read"] == 4 and fr["decoded"] == 3 and fr["rejected_by_reason"] == {"decode_dlc": 1}
    assert res.error is not None and str(log) in res.error and "after frame 4" in res.error


@pytest.mark.parametrize("ref", references(), ids=lambda r: r.name)
def test_reference_traces_replay_to_their_golden_outputs(ref, tmp_path):
    out = tmp_path / "estimates.log"
    summary = replay_reference(TRACES, ref, out)
    golden = golden_path(TRACES, ref)
    assert out.read_bytes() == golden.read_bytes(), (
        f"{ref.name}: replay differs from {golden}; if the ECU changed on purpose, regenerate "
        "with `python -m vecu.replay.reference traces/ --golden` and say why in the commit")
    assert summary["frames"]["rejected"] == 0 and summary["score"] is not None


def test_third_party_dbc_drives_speed_and_steering_through_the_map():
    ref = next(r for r in references() if r.signal_map)
    res = replay(ReplayConfig(trace=str(TRACES / ref.name), dbc=(str(TRACES / ref.dbc[0]),),
                              signal_map=str(TRACES / ref.signal_map), progress=False))
    s = res.summary
    assert s["functions"]["throttle"]["enabled"] is False
    assert "throttle.motor_voltage" in s["functions"]["throttle"]["reason"]
    assert s["functions"]["speed"]["estimates_sent"] == 2000
    assert s["score"]["speed"]["speed_error_kmh"]["rms"] < 0.5  # wheel speed noise ~1.3 km/h
    assert s["score"]["steering"]["swa_estimate_error_deg"]["rms"] < 3.0
    assert any("steering_angle not mapped" in n for n in s["map"]["notes"])


def test_third_party_ids_are_extended_and_not_confused_with_ours():
    db = DbcCodec([TRACES / "dbc" / "vehicle.dbc"])
    assert all(fc.is_extended for fc in db.by_id.values())
