"""Signal maps: unit conversion, validation errors naming file and key, coverage."""

from __future__ import annotations

import math

import pytest

from vecu.codec import DbcCodec
from vecu.replay.signal_map import (
    SignalMapError,
    build_signal_map,
    identity_map,
    load_signal_map,
    unit_conversion,
)


@pytest.mark.parametrize("src,dst,x,y", [
    ("m/s", "km/h", 10.0, 36.0), ("mph", "km/h", 1.0, 1.609344), ("g", "m/s^2", 1.0, 9.80665),
    ("rad", "deg", math.pi, 180.0), ("rad/s", "deg/s", 1.0, 180.0 / math.pi),
    ("rad/s", "rpm", 2 * math.pi, 60.0), ("K", "degC", 300.0, 26.85), ("degF", "degC", 212.0, 100.0),
    ("bar", "kPa", 1.0, 100.0), ("Pa", "kPa", 101325.0, 101.325), ("mV", "V", 4500.0, 4.5),
    ("degrees/s", "deg/s", 3.0, 3.0), ("km/h", "km/h", 5.0, 5.0),
])
def test_unit_conversion(src, dst, x, y):
    f, o = unit_conversion(src, dst)
    assert x * f + o == pytest.approx(y)


@pytest.mark.parametrize("src,dst", [("km/h", "deg"), ("furlong", "km/h"), ("g", "kPa")])
def test_impossible_conversions_raise(src, dst):
    with pytest.raises(ValueError):
        unit_conversion(src, dst)


@pytest.fixture(scope="module")
def vehicle_db():
    from pathlib import Path
    return DbcCodec([Path(__file__).resolve().parents[2] / "traces" / "dbc" / "vehicle.dbc"])


@pytest.mark.parametrize("doc,needle", [
    ({"sped": {}}, "[sped]: unknown function"),
    ({"speed": {"wheel": "RT_SB_Speed.Speed"}}, "speed.wheel: unknown input"),
    ({"speed": {"wheel_speed": "RT_SB_Speed"}}, 'speed.wheel_speed.signal: expected "Message.Signal"'),
    ({"speed": {"wheel_speed": "Nope.Speed"}}, "no message 'Nope'"),
    ({"speed": {"wheel_speed": "RT_SB_Speed.Nope"}}, "has no signal 'Nope'"),
    ({"speed": {"wheel_speed": {"signal": "RT_SB_Speed.Speed", "unit": "deg"}}},
     "speed.wheel_speed.unit: cannot convert"),
    ({"speed": {"wheel_speed": {"signal": "RT_SB_Speed.Speed", "scale": "x"}}},
     "speed.wheel_speed.scale: expected a finite number"),
    ({"speed": {"wheel_speed": {"signal": "RT_SB_Speed.Speed", "colour": 1}}},
     "unknown key 'colour'"),
])
def test_bad_maps_name_the_key(vehicle_db, doc, needle):
    with pytest.raises(SignalMapError) as err:
        build_signal_map(doc, vehicle_db, "my.toml")
    assert str(err.value).startswith("my.toml: ") and needle in str(err.value)


def test_map_uses_the_dbc_unit_and_scale_offset(vehicle_db):
    smap = build_signal_map({"speed": {
        "wheel_speed": "RT_SB_Speed.Speed",
        "long_accel": {"signal": "RT_IMU06_Accel.Accel_Longitudinal", "scale": -1.0}}},
        vehicle_db)
    by = {m.name: m for m in smap.inputs}
    assert by["wheel_speed"].factor == pytest.approx(3.6) and by["wheel_speed"].source_unit == "m/s"
    assert by["long_accel"].factor == pytest.approx(-9.80665)
    assert set(smap.disabled) == {"throttle", "steering", "manifold"}
    assert "speed" not in smap.disabled


def test_identity_map_covers_all_functions_on_vecus_own_dbc():
    smap = identity_map(DbcCodec())
    assert smap.disabled == {} and smap.notes == ()
    assert len(smap.inputs) == 14


def test_load_signal_map_errors(tmp_path, vehicle_db):
    with pytest.raises(SignalMapError, match="no such file"):
        load_signal_map(tmp_path / "none.toml", vehicle_db)
    bad = tmp_path / "bad.toml"
    bad.write_text("[speed\n")
    with pytest.raises(SignalMapError, match="bad.toml: TOML syntax error"):
        load_signal_map(bad, vehicle_db)


def test_mapped_manifold_inputs_match_native_replay(tmp_path):
    """The manifold function fed through a map (no E2E, synthesised event counters) scores like
    the native replay, also when ENG_Intake frames go missing: a synthesised ENG_Intake carries
    the counter of its ENG_Event, so the IAT stays paired with the right event."""
    from pathlib import Path

    import can

    from vecu.codec import TRUTH_DBC, builtin_dbc_path
    from vecu.replay.engine import ReplayConfig, replay
    src = Path(__file__).resolve().parents[2] / "traces" / "drive_tps_dead.blf"
    trace = str(tmp_path / "lossy.blf")
    intake = 0
    with can.Logger(trace) as w:
        for m in can.LogReader(str(src)):
            if m.arbitration_id == 0x111:
                intake += 1
                if intake % 10 == 5:
                    continue  # lose every 10th ENG_Intake frame
            w.on_message_received(m)
    smap = tmp_path / "engine.toml"
    smap.write_text('[manifold]\nengine_speed = "ENG_Event.ENG_Speed"\n'
                    'throttle_setpoint = "ENG_Event.ENG_ThrottleSetpoint"\n'
                    'throttle_angle = "ENG_Event.ENG_ThrottleAngle"\nmap = "ENG_Event.ENG_MAP"\n'
                    'iat = { signal = "ENG_Intake.ENG_IAT", unit = "K", offset = 273.15 }\n')
    native = replay(ReplayConfig(trace=trace, progress=False)).summary
    mapped = replay(ReplayConfig(trace=trace, progress=False, signal_map=str(smap),
                                 dbc=(str(builtin_dbc_path()), str(builtin_dbc_path(TRUTH_DBC))))
                    ).summary
    assert set(mapped["functions"]) == {"throttle", "speed", "steering", "manifold"}
    assert [k for k, f in mapped["functions"].items() if f["enabled"]] == ["manifold"]
    a, b = native["score"]["manifold"], mapped["score"]["manifold"]
    assert b["map_error_kpa"]["n"] == a["map_error_kpa"]["n"] > 100
    assert b["imt_error_k"]["rms"] == pytest.approx(a["imt_error_k"]["rms"], rel=1e-6)
    assert b["map_error_kpa"]["rms"] == pytest.approx(a["map_error_kpa"]["rms"], rel=1e-6)
