"""Signal maps: unit conversion, validation errors naming file and key, coverage."""

from __future__ import annotations

import math

import pytest

from vecu.codec import DbcCodec
from vecu.replay.signal_map import (SignalMapError, build_signal_map, identity_map,
                                    load_signal_map, unit_conversion)


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
    return DbcCodec([Path(__file__).resolve().parents[1] / "traces" / "dbc" / "vehicle.dbc"])


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
    with pytest.raises(SignalMapError, match="bad.toml: not valid TOML"):
        load_signal_map(bad, vehicle_db)
