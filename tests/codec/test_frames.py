"""The generated frame() (FrameCodec.framer): make(ts, *values) gives exactly FrameCodec.frame's
Message, or raises what frame() raises, and beside it the values that Message carries (cantools'
decode of its payload, though nothing decodes it), on every message of vecu's DBCs and the
third-party ones; the generated bad_values and decode_checked against the loop they replace."""

from __future__ import annotations

import math
import random

import cantools
import numpy as np
import pytest

from tests.codec.dbc_sets import every_message
from vecu.can_message import same_message
from vecu.codec import DbcCodec, builtin_dbc_path
from vecu.codec.source import compile_source, message_source

RUNS = 120  # value sets per message


def _value(sig, rng: random.Random) -> object:
    lo = sig.minimum if sig.minimum is not None else -1000.0
    hi = sig.maximum if sig.maximum is not None else 1000.0
    pick = rng.random()
    if pick < 0.45:
        return rng.uniform(lo - 0.2 * (hi - lo) - 1, hi + 0.2 * (hi - lo) + 1)
    if pick < 0.7:
        return rng.randint(int(lo), int(hi))
    if pick < 0.85:
        return rng.choice([math.nan, math.inf, -math.inf, lo, hi, 0, -0.0])
    return rng.choice([True, np.float64(1.5), np.int64(2), 1e300, -(2 ** 70)])


@pytest.mark.parametrize("with_thirdparty", [False, True])
def test_framer_gives_frames_message(with_thirdparty, request):
    rng = random.Random(5)
    checked = 0
    for fc in every_message(request, with_thirdparty):
        names = [s.name for s in fc.signals]
        if not names:
            continue
        make = fc.framer(names)
        for _ in range(RUNS if not with_thirdparty else RUNS // 4):
            values = [_value(fc.signal(n), rng) for n in names]
            ts = rng.uniform(0.0, 100.0)
            try:
                ref = fc.frame(dict(zip(names, values)), ts)
            except Exception as exc:  # noqa: BLE001 - the framer must raise the same
                with pytest.raises(type(exc)):
                    make(ts, *values)
                continue
            msg, carried = make(ts, *values)
            assert same_message(msg, ref), (fc.name, names, values)
            try:
                decoded = fc.decode_cantools(msg.data)  # cantools, the reference
            except Exception:  # noqa: BLE001 - cantools encoded what it cannot decode
                decoded = {}
            assert _same_numbers(carried, [decoded.get(n) for n in names]), (fc.name, values)
            checked += 1
    assert checked > 500


def _same_numbers(a, b) -> bool:
    """Equal number for number (NaN equal to NaN: a float signal may carry one)."""
    return len(a) == len(b) and all(x == y or (x != x and y != y) for x, y in zip(a, b))


def test_framer_refuses_names_that_are_not_the_signals():
    fc = DbcCodec()["TPS_Sensor"]
    with pytest.raises(ValueError):
        fc.framer(("TPS_Voltage",))
    with pytest.raises(ValueError):
        fc.framer(("TPS_CRC", "TPS_AliveCounter", "TPS_Voltage", "TPS_Voltage"))
    with pytest.raises(ValueError):  # the values' order is the DBC's
        fc.framer(("TPS_AliveCounter", "TPS_CRC", "TPS_Voltage"))


def _bad_values_reference(checked, values) -> list[str]:
    """FrameCodec.bad_values as the loop it was before it was generated."""
    bad = []
    for name, lo, hi in checked:
        value = values.get(name)
        if value is None:
            continue
        if not math.isfinite(value) or (lo is not None and value < lo) or (
                hi is not None and value > hi):
            bad.append(name)
    return bad


def test_generated_range_check_is_the_loop():
    rng = random.Random(9)
    checked = [("a", -1.5, 2.0), ("b", None, 10), ("c", 0, None), ("d", None, None),
               ("e", -math.inf, 3.0), ("f", 1.0, 1.0)]
    bad_values = _generated(checked, decode=None).bad_values
    specials = [math.nan, math.inf, -math.inf, -1.5, 2.0, 10, 0, 1.0, -0.0, 3.0]
    for _ in range(3000):
        values = {n: (rng.choice(specials) if rng.random() < 0.5 else rng.uniform(-20, 20))
                  for n, _, _ in checked if rng.random() < 0.9}
        assert bad_values(values) == _bad_values_reference(checked, values), values
    for fc in DbcCodec().by_id.values():  # every message's own check, on in- and out-of-range
        for _ in range(50):
            values = {s.name: rng.choice(specials + [rng.uniform(-1e4, 1e4)]) for s in fc.signals}
            assert fc.bad_values(values) == _bad_values_reference(fc._checked, values)


def test_decode_checked_is_decode_then_bad_values():
    """FrameCodec.decode_checked (the receive path's one call) = (decode_exact, bad_values),
    on payloads whose signals are in and out of their DBC ranges; a restricted codec's too."""
    rng = random.Random(4)
    codec = DbcCodec()
    for fc in [*codec.by_id.values(), codec["TPS_Sensor"].checking_only(())]:
        for _ in range(300):
            data = bytearray(rng.getrandbits(8 * fc.length).to_bytes(fc.length, "little"))
            values, bad = fc.decode_checked(data)
            assert values == fc.decode_exact(data) or math.isnan(sum(values.values()))
            assert bad == fc.bad_values(fc.decode_exact(data)), (fc.name, data.hex())
    pieces = {"a": 1.0, "b": math.nan}  # an incomplete decoder: its missing signals not checked
    check = _generated([("a", 0, 2), ("b", 0, 1), ("c", 0, 1)],
                       decode=lambda data: dict(pieces)).decode_checked
    assert check(b"") == (pieces, ["b"])


def _generated(checked, decode):
    """The functions of a source generated for vecu's TPS_Sensor with another range check and
    (plain=False) another decoder."""
    db = cantools.database.load_file(str(builtin_dbc_path()))
    return compile_source(message_source(
        db.get_message_by_name("TPS_Sensor"), saturate=(), checked=checked, protect=None,
        decode_fallback=decode, frame_fallback=None, plain=decode is None))
