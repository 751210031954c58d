"""SecurityAccess (0x27) level 1: seed, key algorithm, failed-attempt counter and delay.

Key algorithm (docs/uds.md): key = (rotl32(seed XOR 0x56454355, 7) + 0x00001D0F) mod 2**32,
seed and key 4 bytes big-endian. 0x56454355 is "VECU" in ASCII.

Seeds: from the OS's entropy (`secrets`) unless a generator is given: a live ECU gives a
different seed after every start, so a sniffed key never works again; the simulated clock
(and `vecu ecu --security-seed N`) draws them from a seeded generator, reproducibly.
"""

from __future__ import annotations

import secrets

import numpy as np

KEY_XOR = 0x56454355
KEY_ADD = 0x00001D0F
KEY_ROTATE = 7
SEED_BYTES = 4


def key_from_seed(seed: bytes) -> bytes:
    """The key a tester must send for `seed` (4 bytes)."""
    x = int.from_bytes(seed, "big") ^ KEY_XOR
    x = ((x << KEY_ROTATE) | (x >> (32 - KEY_ROTATE))) & 0xFFFFFFFF
    return ((x + KEY_ADD) & 0xFFFFFFFF).to_bytes(SEED_BYTES, "big")


class SecurityAccess:
    """Lock state of level 1. request_seed()/send_key() return the response data or an NRC."""

    def __init__(self, rng: np.random.Generator | None, attempts: int, delay_ns: int) -> None:
        """rng: the seeds' generator; None: the OS's entropy."""
        self._rng = rng
        self.max_attempts = attempts
        self.delay_ns = delay_ns
        self.unlocked = False
        self.failed = 0              # failed keys since the last success or delay
        self.failed_total = 0
        self._seed: bytes | None = None
        self._delay_until: int | None = None

    def lock(self) -> None:
        self.unlocked = False
        self._seed = None

    def request_seed(self, t_ns: int) -> bytes | int:
        if self._delay_until is not None:
            if t_ns < self._delay_until:
                return 0x37  # requiredTimeDelayNotExpired
            self._delay_until = None
            self.failed = 0
        if self.unlocked:
            return bytes(SEED_BYTES)  # already unlocked: the all-zero seed (ISO 14229-1)
        seed = (bytes(self._rng.integers(1, 256, SEED_BYTES, dtype=np.uint8)) if self._rng is not None
                else bytes(1 + secrets.randbelow(255) for _ in range(SEED_BYTES)))
        self._seed = seed
        return seed

    def send_key(self, t_ns: int, key: bytes) -> bytes | int:
        if self._delay_until is not None and t_ns < self._delay_until:
            return 0x37
        if self._seed is None:
            return 0x24  # requestSequenceError: no seed requested
        seed, self._seed = self._seed, None  # one key per seed
        if key == key_from_seed(seed):
            self.unlocked = True
            self.failed = 0
            return b""
        self.failed += 1
        self.failed_total += 1
        if self.failed >= self.max_attempts:
            self._delay_until = t_ns + self.delay_ns
            return 0x36  # exceededNumberOfAttempts: the delay starts
        return 0x35  # invalidKey
