"""The generated shift-and-mask codec (vecu.codec.source: encode / decode) against cantools itself:
bit for bit on every message of vecu's DBCs and of the 21 third-party DBCs, random values."""

from __future__ import annotations

import math
import random
import struct

import cantools
import numpy as np
import pytest

from vecu.codec import DbcCodec, builtin_dbc_path
from vecu.codec.source import compile_source, message_source

RUNS = 150  # random payloads and value sets per message


def _databases(thirdparty_dir):
    paths = [builtin_dbc_path(), builtin_dbc_path("vecu_truth.dbc")]
    if thirdparty_dir is not None:
        paths += sorted((thirdparty_dir / "dbc").glob("*.dbc"))
    for path in paths:
        db = cantools.database.Database(strict=False)
        db.add_dbc_file(str(path))
        yield path.name, db


def _same(a, b) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


def _random_values(msg, rng, pyrng) -> dict[str, float]:
    """Physical values a sender may pass: raw grid points, off-grid points, the raw ends."""
    values = {}
    for sig in msg.signals:
        if sig.is_float:
            pick = rng.integers(4)
            v = (float(rng.normal(0.0, 10.0) * 10.0 ** rng.integers(-3, 6)) if pick < 3
                 else float(rng.choice([0.0, -0.0, math.inf, 1e-40])))
            values[sig.name] = v
            continue
        lo, hi = ((-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.is_signed
                  else (0, (1 << sig.length) - 1))
        raw = [lo, hi, pyrng.randint(lo, hi)][int(rng.integers(3))]
        conv = sig.conversion
        phys = raw * conv.scale + conv.offset
        if rng.random() < 0.4:  # off the grid by less than half an LSB
            phys += float(rng.uniform(-0.45, 0.45)) * abs(conv.scale) * (raw not in (lo, hi))
        values[sig.name] = phys if rng.random() < 0.9 else round(phys)
    return values


@pytest.mark.parametrize("with_thirdparty", [False, True])
def test_fast_codec_is_bit_identical_to_cantools(with_thirdparty, request):
    tp = request.getfixturevalue("thirdparty") if with_thirdparty else None
    rng = np.random.default_rng(11)
    pyrng = random.Random(11)  # raw values of 64-bit signals
    compiled = total = 0
    for name, db in _databases(tp):
        if with_thirdparty and name.startswith("vecu"):
            continue
        for msg in db.messages:
            total += 1
            made = compile_source(message_source(
                msg, saturate=(), checked=(), protect=None, decode_fallback=msg.decode,
                frame_fallback=None))
            if made.encode is None:
                continue
            compiled += 1
            enc, dec = made.encode, made.decode
            for _ in range(RUNS):
                data = bytes(rng.integers(0, 256, msg.length, dtype=np.uint8))
                got, ref = dec(data), msg.decode_simple(data, False, True)
                assert list(got) == list(ref), (name, msg.name)
                assert all(_same(got[k], ref[k]) for k in ref), (name, msg.name, data.hex())
                values = _random_values(msg, rng, pyrng)
                try:
                    ref_bytes = msg.encode(values, scaling=True, padding=False, strict=False)
                except Exception:  # noqa: BLE001 (cantools refuses e.g. a float too large)
                    ref_bytes = None
                try:
                    got_bytes = enc(values)
                except Exception:  # noqa: BLE001 - the fast path declines: any error
                    got_bytes = None  # FrameCodec.encode then asks cantools
                if got_bytes is not None:
                    assert got_bytes == ref_bytes, (name, msg.name, values)
    assert compiled >= (30 if with_thirdparty else 20)
    assert compiled < total or not with_thirdparty  # multiplexed messages keep cantools


def test_frame_codec_saturation_and_e2e_match_the_cantools_path():
    codec = DbcCodec()
    rng = np.random.default_rng(3)
    for fc in codec.by_id.values():
        assert fc._fast_encode is not None, fc.name
        for _ in range(RUNS):
            values = {}
            saturated = {name for name, _, _ in fc._saturate}
            for sig in fc.signals:
                if sig.name not in saturated:  # full-range integers (CRC, counters, enums)
                    values[sig.name] = int(rng.integers(1 << sig.length))
                    continue
                lo, hi = fc.ranges[sig.name]
                span = (hi - lo) if lo is not None and hi is not None else 100.0
                base = lo if lo is not None else 0.0
                values[sig.name] = float(rng.choice([
                    rng.uniform(base - span, base + 2 * span), math.nan, -math.inf, math.inf,
                    base + span * rng.random()]))
            if fc.e2e is not None:
                values[fc.e2e.counter_signal] = int(rng.integers(fc.e2e.protection.counter_modulo))
            fast, ref = fc.encode(values), fc.encode_cantools(values)
            assert fast == ref, (fc.name, values)
            assert fc.crc_ok(fast)
            assert all(_same(a, b) for a, b in zip(fc.decode(fast).values(),
                                                   fc.decode_cantools(fast).values()))


def test_unusual_input_goes_through_cantools():
    fc = DbcCodec()["TPS_Sensor"]
    with pytest.raises(KeyError):
        fc.encode({"TPS_CRC": 0, "TPS_AliveCounter": 1})  # missing signal: cantools' error
    with pytest.raises(TypeError):
        fc.encode({"TPS_CRC": 0, "TPS_AliveCounter": 1, "TPS_Voltage": "high"})
    # a counter that does not fit its 4 bits: whatever cantools does, FrameCodec does
    values = {"TPS_CRC": 0, "TPS_AliveCounter": 17, "TPS_Voltage": 1.0}
    try:
        expected = fc.encode_cantools(values)
    except Exception as exc:  # noqa: BLE001 - the fast path must raise the same
        with pytest.raises(type(exc)):
            fc.encode(values)
    else:
        assert fc.encode(values) == expected
    with pytest.raises(cantools.database.DecodeError):
        fc.decode(b"\x00\x01")  # short payload: cantools raises
    long = bytes(range(6))
    assert fc.decode(long) == fc.decode_cantools(long)  # excess bytes: cantools trims


def test_float_signal_bits():
    fc = DbcCodec()["ETB_Wattmeter"]
    data = fc.encode({"ETB_Voltage": 1.0, "ETB_Power": 1234.5678})
    assert struct.unpack_from("<f", data, 4)[0] == pytest.approx(1234.5678, rel=1e-7)
    assert data == fc.encode_cantools({"ETB_Voltage": 1.0, "ETB_Power": 1234.5678})
