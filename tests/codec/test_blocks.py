"""Block decoding (vecu.codec.blocks, FrameCodec.check_block) against the per-frame path: for many
random payloads of every message of vecu's DBCs and of the third-party DBCs, the CRC verdict,
every value (type and bits) and the out-of-range names are what crc_ok / decode / bad_values give
one frame at a time."""

from __future__ import annotations

import math
import random
import struct

import pytest

from tests.codec.dbc_sets import every_message
from vecu.codec import DbcCodec, builtin_dbc_path

FRAMES = 300  # random payloads per message, decoded as one block


def _same(a, b) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return struct.pack("<d", a) == struct.pack("<d", b) or (math.isnan(a) and math.isnan(b))
    return a == b


def _payloads(fc, rng: random.Random) -> list[bytes]:
    out = []
    for k in range(FRAMES):
        data = bytearray(rng.getrandbits(8) for _ in range(fc.length))
        if fc.e2e is not None and k % 2:  # half of them with a valid CRC
            fc.e2e.protection.protector()(data)  # autosar-e2e writes the CRC
        if k % 7 == 0:  # all ones / all zeros: the raw ends of every signal
            data = bytearray([0xFF if k % 14 else 0x00] * fc.length)
        out.append(bytes(data))
    return out


@pytest.mark.parametrize("with_thirdparty", [False, True])
def test_block_check_is_the_per_frame_checks_bit_for_bit(with_thirdparty, request):
    rng = random.Random(16)
    blocks = 0
    for fc in every_message(request, with_thirdparty):
        if fc.block is None:
            continue
        blocks += 1
        payloads = _payloads(fc, rng)
        got = fc.check_block(payloads)
        assert len(got) == len(payloads)
        for k, data in enumerate(payloads):
            ok, values, bad = got[k]
            want = fc.decode(data)
            assert ok == fc.crc_ok(data), (fc.name, data.hex())
            assert list(values) == list(want), fc.name
            assert all(_same(values[k], want[k]) for k in want), (fc.name, data.hex(),
                                                                  values, want)
            assert bad == fc.bad_values(want), (fc.name, data.hex())
    assert blocks >= (20 if not with_thirdparty else 200)


def test_every_message_of_vecus_dbcs_has_a_block_layout_and_a_restricted_codec_checks_less():
    db = DbcCodec([builtin_dbc_path(), builtin_dbc_path("vecu_truth.dbc")])
    assert all(fc.block is not None for fc in db.by_id.values())
    tps = db["TPS_Sensor"]
    data = bytes([0xFF] * tps.length)
    assert tps.check_block([data])[0][2] == tps.bad_values(tps.decode(data)) != []
    none = tps.checking_only([])
    assert none.check_block([data])[0][2] == [] == none.bad_values(none.decode(data))


def _values_to_encode(fc, payloads, rng: random.Random) -> list[list[float]]:
    """Per signal a column: the decoded values of the payloads, with values past the DBC
    range, NaN, +-inf and 1e40 mixed in (saturated, refused or sent to the per-frame path)."""
    rows = [fc.decode(p) for p in payloads]
    cols = []
    for sig in fc.signals:
        col = [float(r[sig.name]) if isinstance(r[sig.name], (int, float)) else 0.0 for r in rows]
        lo, hi = fc.ranges[sig.name]
        for k in range(len(col)):
            if k % 11 == 3:
                col[k] = rng.choice([math.nan, math.inf, -math.inf, 1e40, -1e40,
                                     (hi if hi is not None else 0.0) + 1.0,
                                     (lo if lo is not None else 0.0) - 1.0, 2.5, 0.5])
        cols.append(col)
    return cols


@pytest.mark.parametrize("with_thirdparty", [False, True])
def test_block_encode_gives_the_framers_payloads(with_thirdparty, request):
    """encode_rows: every row it encodes is the payload FrameCodec.framer's make() sends (the
    E2E CRC included); the rows it leaves go to make()."""
    rng = random.Random(17)
    encoded = refused = 0
    for fc in every_message(request, with_thirdparty):
        names = tuple(s.name for s in fc.signals)
        if fc.block is None or not names:
            continue
        cols = _values_to_encode(fc, _payloads(fc, rng), rng)
        got = fc.encode_rows(names, cols)
        if got is None:
            continue
        payloads, left = got
        make = fc.framer(names)
        for k in range(len(cols[0])):
            if left[k]:
                refused += 1
                continue
            want, _ = make(0.0, *(c[k] for c in cols))
            assert payloads[k].tobytes() == bytes(want.data), (fc.name, k)
            encoded += 1
    assert encoded > (5000 if not with_thirdparty else 50_000) and refused > 0
