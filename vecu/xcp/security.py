"""XCP seed & key (GET_SEED / UNLOCK) for the CAL/PAG, DAQ and PGM resources.

Off by default (`ecu.xcp.seed_key = false`: every resource unlocked). On, every resource is
locked at CONNECT; GET_SEED(mode 0, resource) gives a 4-byte seed from the run's seeded stream
'xcp.security', and UNLOCK takes

    key = SHA-256(secret || resource || seed)[:4]

with `secret` = `ecu.xcp.secret` (ASCII) and `resource` the one resource byte (0x01 CAL/PAG,
0x04 DAQ, 0x10 PGM). A wrong key answers ERR_ACCESS_LOCKED and the slave disconnects (the
standard's rule); UNLOCK without a seed is ERR_SEQUENCE. docs/xcp.md gives a pyxcp
seed_n_key_function for it.
"""

from __future__ import annotations

import hashlib

import numpy as np

CAL_PAG, DAQ, PGM = 0x01, 0x04, 0x10
RESOURCES = (CAL_PAG, DAQ, PGM)
SEED_LEN = 4
ERR_OUT_OF_RANGE, ERR_ACCESS_LOCKED, ERR_SEQUENCE = 0x22, 0x25, 0x29


def xcp_key(secret: str, resource: int, seed: bytes) -> bytes:
    """The key for a seed (the algorithm above)."""
    return hashlib.sha256(secret.encode("ascii") + bytes([resource]) + bytes(seed)).digest()[:4]


class SeedKeyError(Exception):
    def __init__(self, code: int, disconnect: bool = False) -> None:
        super().__init__(code)
        self.code = code
        self.disconnect = disconnect


class SeedKey:
    """Which resources are locked, and the seed last given."""

    def __init__(self, enabled: bool, secret: str, rng: np.random.Generator) -> None:
        self.enabled = enabled
        self.secret = secret
        self._rng = rng
        self.locked = 0
        self._pending: tuple[int, bytes] | None = None
        self.failed = 0
        self.lock_all()

    def lock_all(self) -> None:
        self.locked = (CAL_PAG | DAQ | PGM) if self.enabled else 0
        self._pending = None

    def get_seed(self, mode: int, resource: int) -> bytes:
        """GET_SEED's response data: length, seed (length 0: the resource is unlocked)."""
        if mode != 0 or resource not in RESOURCES:
            raise SeedKeyError(ERR_OUT_OF_RANGE)
        if not self.locked & resource:
            self._pending = None
            return b"\x00"
        seed = bytes(self._rng.integers(0, 256, SEED_LEN, dtype=np.uint8).tolist())
        self._pending = (resource, seed)
        return bytes([SEED_LEN]) + seed

    def unlock(self, length: int, key: bytes) -> bytes:
        """UNLOCK's response data: the resource protection status."""
        if self._pending is None:
            raise SeedKeyError(ERR_SEQUENCE)
        resource, seed = self._pending
        self._pending = None
        if length != len(key) or key != xcp_key(self.secret, resource, seed):
            self.failed += 1
            raise SeedKeyError(ERR_ACCESS_LOCKED, disconnect=True)
        self.locked &= ~resource
        return bytes([self.locked])
