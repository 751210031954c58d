"""Requests of every ISO-TP length for the sweeps of issue 29 (simulated: tests/uds/
test_isotp_lengths.py; live: tests/live/isotp_sweep_live.py) and the answer ISO 14229 owes each.

The request of length L is ReadDataByIdentifier 0x22 followed by L - 1 bytes of the DID 0xF186
(active session, 1 byte) repeated: a whole number of DIDs up to max_dids_per_request (16) is
answered 62 + (F1 86 01) per DID in the default session; an odd byte count, no DID at all or
more than 16 DIDs is 7F 22 13 (incorrectMessageLengthOrInvalidFormat)."""

from __future__ import annotations

MAX_LENGTH = 4095  # ISO 15765-2 classic first frame: 12-bit length
MAX_DIDS = 16      # ecu.uds.max_dids_per_request (default)


def request(length: int) -> bytes:
    return (b"\x22" + b"\xf1\x86" * 2048)[:length]


def expected(length: int) -> bytes:
    n = length - 1
    if n == 0 or n % 2 or n // 2 > MAX_DIDS:
        return b"\x7f\x22\x13"
    return b"\x62" + b"\xf1\x86\x01" * (n // 2)
