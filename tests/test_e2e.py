"""vecu.e2e: the AUTOSAR profiles through autosar-e2e, checked against the library's own check
over >= 10^5 frames each, P02 / P05 against cantools' profile functions (a second oracle), and
vecu's own safety frames against P11 with the data ID = the CAN ID."""

from __future__ import annotations

import random

import cantools.autosar as cantools_e2e
import e2e as autosar_e2e
import pytest

from vecu.codec import DbcCodec
from vecu.e2e import PROFILES, AliveCounterCheck, E2EConfigError, E2EProtection

N_FRAMES = 100_000

CONFIGS = {
    "P01": E2EProtection("P01", data_id=0x1B0, data_id_mode="nibble"),
    "P02": E2EProtection("P02", data_id_list=tuple(range(0x10, 0x20))),
    "P04": E2EProtection("P04", data_id=0x0A0B0C0D, length=16),
    "P05": E2EProtection("P05", data_id=0x01B0),
    "P07": E2EProtection("P07", data_id=0x12345678, length=24),
    "P11": E2EProtection("P11", data_id=0x200, data_id_mode="both"),
}
LENGTHS = {"P04": 16, "P07": 24}


def _frames(prot: E2EProtection, n: int, seed: int):
    """n payloads protected by vecu's protector with the counter running +1 (mod the profile)."""
    rng = random.Random(seed)
    protect = prot.protector()
    size = LENGTHS.get(prot.profile, 8)
    for k in range(n):
        buf = bytearray(rng.getrandbits(8 * size).to_bytes(size, "little"))
        prot.set_counter(buf, k % prot.counter_modulo)
        protect(buf)
        yield k, buf


def test_every_profile_of_the_issue_is_registered():
    assert set(PROFILES) == {"P01", "P02", "P04", "P05", "P07", "P11"}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_each_profile_passes_the_librarys_own_check_over_1e5_frames(name):
    prot = CONFIGS[name]
    kw = dict(prot._kw)
    lib_check = {"P01": autosar_e2e.p01.e2e_p01_check, "P02": autosar_e2e.p02.e2e_p02_check,
                 "P04": autosar_e2e.p04.e2e_p04_check, "P05": autosar_e2e.p05.e2e_p05_check,
                 "P07": autosar_e2e.p07.e2e_p07_check,
                 "P11": autosar_e2e.p11.e2e_p11_check}[name]
    counter = AliveCounterCheck(prot.counter_modulo)
    flipped = 0
    for k, buf in _frames(prot, N_FRAMES, seed=hash(name) & 0xFFFF):
        assert lib_check(buf, **kw), (name, k, buf.hex())
        assert counter.check(prot.counter(buf)), (name, k)
        if k % 1000 == 0:  # one flipped bit anywhere protected fails the check
            bit = k // 1000 % (8 * len(buf))
            buf[bit // 8] ^= 1 << (bit % 8)
            covered = bit // 8 < (prot.length or len(buf))
            if covered and not (name in ("P01", "P11") and bit // 8 == 1 and bit % 8 >= 4
                                and prot.data_id_mode == "both"):
                assert not lib_check(buf, **kw), (name, k, bit)
                flipped += 1
    assert flipped > 50


@pytest.mark.parametrize("name", ["P02", "P05"])
def test_p02_and_p05_frames_pass_cantools_profile_functions_too(name):
    prot = CONFIGS[name]
    for _, buf in _frames(prot, N_FRAMES, seed=5):
        if name == "P02":  # cantools takes the data ID this counter value selects
            assert cantools_e2e.check_profile2_crc(bytes(buf), prot.data_id_list[buf[1] & 0xF])
        else:
            assert cantools_e2e.check_profile5_crc(bytes(buf), prot.data_id)


def test_counter_ranges_follow_the_profiles():
    assert {n: p.counter_modulo for n, p in PROFILES.items()} == {
        "P01": 15, "P02": 16, "P04": 1 << 16, "P05": 256, "P07": 1 << 32, "P11": 15}


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_set_counter_and_counter_round_trip_and_the_library_increments_the_same_field(name):
    prot = CONFIGS[name]
    buf = bytearray(LENGTHS.get(name, 8))
    prot.set_counter(buf, 7)
    assert prot.counter(buf) == 7
    kw = dict(prot._kw)
    lib = {"P01": autosar_e2e.p01.e2e_p01_protect, "P02": autosar_e2e.p02.e2e_p02_protect,
           "P04": autosar_e2e.p04.e2e_p04_protect, "P05": autosar_e2e.p05.e2e_p05_protect,
           "P07": autosar_e2e.p07.e2e_p07_protect, "P11": autosar_e2e.p11.e2e_p11_protect}[name]
    lib(buf, increment_counter=True, **kw)
    assert prot.counter(buf) == 8  # vecu reads the counter where the library keeps it


@pytest.mark.parametrize("kwargs,problem", [
    ({"profile": "P03"}, "unknown E2E profile"),
    ({"profile": "P11", "data_id": 1 << 16}, "does not fit"),
    ({"profile": "P02", "data_id_list": (1, 2)}, "16 values"),
    ({"profile": "P05", "data_id_mode": "nibble"}, ""),  # no modes: the mode is not used
    ({"profile": "P11", "data_id_mode": "alt"}, "unknown data_id_mode"),
    ({"profile": "P02", "data_id_list": tuple(range(16)), "offset": 2}, "no offset"),
])
def test_bad_configurations_are_refused_with_the_reason(kwargs, problem):
    if not problem:
        E2EProtection(**kwargs)
        return
    with pytest.raises(E2EConfigError, match=problem):
        E2EProtection(**kwargs)


def test_fits_names_a_message_too_short_for_its_header():
    assert E2EProtection("P05", data_id=1).fits(2) is not None
    assert E2EProtection("P04", data_id=1).fits(8) is not None
    assert E2EProtection("P11", data_id=1, offset=6).fits(8) is None
    assert "exceeds" in E2EProtection("P11", data_id=1, length=9).fits(8)


@pytest.mark.parametrize("message", ["TPS_Sensor", "SWA_Sensor", "ECU_ThrottleEstimate",
                                     "ECU_SteeringEstimate"])
def test_vecus_own_safety_frames_pass_autosar_p11_with_the_can_id_as_data_id(message):
    fc = DbcCodec()[message]
    prefix = fc.e2e.crc_signal.rsplit("_", 1)[0]
    rng = random.Random(3)
    for k in range(2000):
        values = {s.name: rng.uniform(s.minimum, s.maximum) for s in fc.signals}
        values[f"{prefix}_AliveCounter"] = k % 15
        data = bytearray(fc.encode(values))
        assert autosar_e2e.p11.e2e_p11_check(
            data, fc.frame_id, data_id_mode=autosar_e2e.p11.E2E_P11_DATAID_BOTH), (message, k)
        assert fc.crc_ok(data)
        data[2] ^= 0x10
        assert not fc.crc_ok(data)


def test_alive_counter_accepts_increments_and_wraps():
    chk = AliveCounterCheck(15)
    assert all(chk.check(k % 15) for k in range(40))


def test_alive_counter_flags_repeat_jump_and_out_of_range_then_resyncs():
    chk = AliveCounterCheck(15)
    assert chk.check(3) and chk.check(4)
    assert not chk.check(4)      # repeated
    assert chk.check(5)
    assert not chk.check(9)      # jumped (frames lost or replayed)
    assert chk.check(10)         # resynchronised
    assert not chk.check(15)     # P11 never sends 15
    assert chk.check(0)


@pytest.mark.parametrize("prot", [
    E2EProtection("P11", data_id=0x200), E2EProtection("P01", data_id=0x1B0),
    E2EProtection("P05", data_id=0x01B0), E2EProtection("P11", data_id=0x3FF, offset=2),
    E2EProtection("P11", data_id=0x200, data_id_mode="nibble")], ids=repr)
def test_protect_and_check_equal_the_librarys_keyword_calls_for_every_counter_value(prot):
    """protector() / checker() pass the data ID positionally and, for a nibble counter, let the
    library increment from the value before (no keyword arguments): the same bytes and verdicts
    as the calls with every keyword, for every counter value the field holds (15 too)."""
    kind, kw = prot.kind, prot._kw
    protect, ok = prot.protector(), prot.checker()
    rng = random.Random(11)
    for k in range(3000):
        buf = bytearray(rng.getrandbits(64).to_bytes(8, "little"))
        if kind.counter_bytes == 0:
            at = prot.offset + kind.counter_at
            buf[at] = (buf[at] & 0xF0) | (k % 16)
        want = bytearray(buf)
        kind.protect(want, increment_counter=False, **kw)
        protect(buf)
        assert buf == want, (k, buf.hex(), want.hex())
        if k % 3:
            buf[rng.randrange(8)] ^= 1 << rng.randrange(8)
        assert ok(buf) == kind.check(bytearray(buf), **kw)
        assert ok(bytes(buf)) == kind.check(bytearray(buf), **kw)
