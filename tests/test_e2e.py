from __future__ import annotations

import random

import pytest

from vecu.e2e import AliveCounterCheck, crc8_sae_j1850, e2e_checker, e2e_crc


@pytest.mark.parametrize("data,crc", [
    # AUTOSAR SWS CRC Library, CRC8 SAE J1850 check values
    (bytes.fromhex("00000000"), 0x59),
    (bytes.fromhex("F20183"), 0x37),
    (bytes.fromhex("0FAA0055"), 0x79),
    (bytes.fromhex("00FF5511"), 0xB8),
    (bytes.fromhex("332255AABBCCDDEEFF"), 0xCB),
    (bytes.fromhex("926B55"), 0x8C),
    (bytes.fromhex("FFFFFFFF"), 0x74),
    (b"123456789", 0x4B),
])
def test_crc8_sae_j1850_reference_values(data, crc):
    assert crc8_sae_j1850(data) == crc


def test_e2e_crc_covers_data_id_and_skips_crc_byte():
    payload = bytearray(b"\x00\x05\x10\x20")
    c = e2e_crc(0x100, payload, 0)
    assert c == crc8_sae_j1850(bytes([0x00, 0x01]) + payload[1:])
    payload[0] = 0xAB  # the CRC byte itself is not covered
    assert e2e_crc(0x100, payload, 0) == c
    assert e2e_crc(0x101, payload, 0) != c  # a frame under another ID fails


def test_alive_counter_accepts_increments_and_wraps():
    chk = AliveCounterCheck()
    assert all(chk.check(k % 16) for k in range(40))


def test_alive_counter_flags_repeat_and_jump_then_resyncs():
    chk = AliveCounterCheck()
    assert chk.check(3) and chk.check(4)
    assert not chk.check(4)      # repeated
    assert chk.check(5)
    assert not chk.check(9)      # jumped (frames lost or replayed)
    assert chk.check(10)         # resynchronised


def test_e2e_crc_is_the_crc_of_data_id_and_payload_without_the_crc_byte_everywhere():
    import random

    rng = random.Random(16)
    for _ in range(500):
        n = rng.randint(1, 8)
        payload = bytes(rng.getrandbits(8) for _ in range(n))
        idx, data_id = rng.randrange(n), rng.getrandbits(11)
        covered = bytes([data_id & 0xFF, data_id >> 8]) + payload[:idx] + payload[idx + 1:]
        assert e2e_crc(data_id, payload, idx) == crc8_sae_j1850(covered)


def test_e2e_checker_agrees_with_e2e_crc_on_any_length():
    rng = random.Random(4)
    for length in range(1, 9):
        for crc_index in range(length):
            for data_id in (0x5, 0x100, 0x7FF, 0x1ABCDEF):
                ok = e2e_checker(data_id, length, crc_index)
                for _ in range(40):
                    n = length if rng.random() < 0.8 else rng.randint(crc_index + 1, 12)
                    payload = bytearray(rng.randrange(256) for _ in range(n))
                    if rng.random() < 0.5:
                        payload[crc_index] = e2e_crc(data_id, payload, crc_index)
                    assert ok(payload) == (payload[crc_index]
                                           == e2e_crc(data_id, payload, crc_index))
