from __future__ import annotations

import math

import cantools
import pytest

from vecu.codec import DbcCodec, DbcLoadError, builtin_dbc_path, shared_codec


@pytest.fixture(scope="module")
def codec() -> DbcCodec:
    return DbcCodec()


def test_builtin_dbc_loads_strictly_with_cycle_times_units_and_nodes():
    db = cantools.database.load_file(str(builtin_dbc_path()), strict=True)
    names = {m.name: m for m in db.messages}
    assert names["TPS_Sensor"].cycle_time == 1
    assert names["ETB_Wattmeter"].cycle_time == 1
    assert names["ECU_ThrottleEstimate"].cycle_time == 1
    assert names["ECU_Status"].cycle_time == 100
    assert names["TPS_Sensor"].senders == ["PLANT"]
    assert names["ECU_ThrottleEstimate"].senders == ["VECU"]
    assert names["ECU_ThrottleEstimate"].get_signal_by_name("THR_Angle").unit == "deg"
    assert names["TPS_Sensor"].get_signal_by_name("TPS_Voltage").unit == "V"
    for m in db.messages:
        for s in m.signals:
            assert s.receivers, f"{m.name}.{s.name} has no receiver"


def test_roundtrip_and_crc(codec):
    tps = codec["TPS_Sensor"]
    data = tps.encode({"TPS_CRC": 0, "TPS_AliveCounter": 7, "TPS_Voltage": 2.3456})
    assert tps.crc_ok(data)
    values = tps.decode(data)
    assert values["TPS_AliveCounter"] == 7
    assert values["TPS_Voltage"] == pytest.approx(2.3456, abs=1e-4)


def test_every_single_bit_flip_is_caught_by_the_crc(codec):
    est = codec["ECU_ThrottleEstimate"]
    data = est.encode({"THR_CRC": 0, "THR_AliveCounter": 3, "THR_Source": 1, "THR_Angle": 45.0,
                       "THR_AngleEst": 44.0, "THR_AngleEstStd": 3.0, "THR_TpsStatus": 2,
                       "THR_Validity": 2})
    for bit in range(len(data) * 8):
        flipped = bytearray(data)
        flipped[bit // 8] ^= 1 << (bit % 8)
        assert not est.crc_ok(flipped), f"bit {bit} flip not detected"


def test_encode_saturates_out_of_range_and_nan(codec):
    est = codec["ECU_ThrottleEstimate"]
    data = est.encode({"THR_CRC": 0, "THR_AliveCounter": 0, "THR_Source": 0, "THR_Angle": -3.0,
                       "THR_AngleEst": 1e6, "THR_AngleEstStd": math.nan, "THR_TpsStatus": 0,
                       "THR_Validity": 1})
    v = est.decode(data)
    assert v["THR_Angle"] == 0.0 and v["THR_AngleEst"] == 90.0 and v["THR_AngleEstStd"] == 0.0


def test_bad_values_flags_nan_and_out_of_range(codec):
    watt = codec["ETB_Wattmeter"]
    v = watt.decode(watt.encode({"ETB_Voltage": 5.0, "ETB_Power": 3.0}))
    assert watt.bad_values(v) == []
    assert watt.bad_values({**v, "ETB_Power": math.nan}) == ["ETB_Power"]
    assert watt.bad_values({**v, "ETB_Voltage": 13.0}) == ["ETB_Voltage"]


def test_missing_dbc_is_one_line_error_naming_the_file(tmp_path):
    with pytest.raises(DbcLoadError, match="nope.dbc: no such file"):
        DbcCodec([tmp_path / "nope.dbc"])
    bad = tmp_path / "bad.dbc"
    bad.write_text('VERSION ""\n\nBU_: N\n\nBO_ 1 X: 8 N\n SG_ A : 0|8@1+ (1,0) [0|255] "" N\n'
                   ' SG_ B : 4|8@1+ (1,0) [0|255] "" N\n')  # overlapping signals
    with pytest.raises(DbcLoadError) as exc:
        DbcCodec([bad])
    assert str(bad) in str(exc.value) and "\n" not in str(exc.value)


def test_every_third_party_dbc_compiles_strictly(thirdparty):
    """All 21 DBCs from cantools' test suite (mux, FD, floats, big-endian, J1939, 10-byte
    messages) compile into codecs; zero payloads decode or fail with cantools' own error."""
    paths = sorted((thirdparty / "dbc").glob("*.dbc"))
    assert len(paths) == 21
    for path in paths:
        codec = DbcCodec([path], strict=True)
        assert codec.by_id, path.name
        for (frame_id, extended), fc in codec.by_id.items():
            assert fc.frame_id == frame_id and fc.is_extended == extended
            try:
                values = fc.decode(bytes(fc.length))
            except cantools.database.DecodeError:
                continue  # e.g. a multiplexer value 0 that selects no branch
            assert isinstance(fc.bad_values(values), list)


def test_fit_wraps_full_range_integers_and_saturates_the_rest():
    """What a fault may push into a signal (vecu.faults frame stage), made encodable."""
    ev = DbcCodec()["ENG_Event"]
    nan, inf = float("nan"), float("inf")
    assert [ev.fit("ENG_EventCounter", v) for v in (255 + 1, 250 + 10, -1, 17.4, 1e300)] == [
        0, 4, 255, 17, (round(1e300)) % 256]
    assert [ev.fit("ENG_EventCounter", v) for v in (inf, -inf, nan)] == [255, 0, 0]
    assert [ev.fit("ENG_Speed", v) for v in (-5.0, 1e9, 1234.5, nan, inf)] == [
        0.0, 8000.0, 1234.5, 0.0, 8000.0]
    with pytest.raises(KeyError):
        ev.fit("ENG_Nope", 1.0)


def test_shared_codec_is_built_once_and_is_the_default_codec():
    shared = shared_codec()
    assert shared_codec() is shared
    fresh = DbcCodec()
    assert sorted(shared.by_id) == sorted(fresh.by_id)
    values = {"TPS_CRC": 0, "TPS_AliveCounter": 3, "TPS_Voltage": 1.25}
    assert shared["TPS_Sensor"].encode(values) == fresh["TPS_Sensor"].encode(values)
    names = ("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage")
    assert shared["TPS_Sensor"].framer(names) is shared["TPS_Sensor"].framer(list(names))
