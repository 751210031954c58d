"""End-to-end protection: 4-bit alive counter and CRC-8 SAE J1850 (AUTOSAR CRC8, poly 0x1D).

Layout follows AUTOSAR E2E profile 1 in spirit: the CRC covers the 16-bit data ID (the CAN ID,
low byte first) followed by every payload byte except the CRC byte itself.
"""

from __future__ import annotations

from collections.abc import Callable


def _make_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _make_table(0x1D)


def crc8_table() -> tuple[int, ...]:
    """The CRC-8 SAE J1850 lookup table (poly 0x1D) the checks here use (block decoders too)."""
    return _TABLE


def crc8_sae_j1850(data: bytes | bytearray, init: int = 0xFF) -> int:
    """CRC-8 SAE J1850: poly 0x1D, init 0xFF, final XOR 0xFF, not reflected (check 0x4B)."""
    crc = init
    table = _TABLE
    for b in data:
        crc = table[crc ^ b]
    return crc ^ 0xFF


def e2e_crc(data_id: int, payload: bytes | bytearray, crc_index: int) -> int:
    """CRC over data ID (2 bytes, little endian) and payload without the CRC byte."""
    table = _TABLE
    crc = table[table[0xFF ^ (data_id & 0xFF)] ^ ((data_id >> 8) & 0xFF)]
    for b in payload[:crc_index]:
        crc = table[crc ^ b]
    for b in payload[crc_index + 1:]:
        crc = table[crc ^ b]
    return crc ^ 0xFF


def e2e_checker(data_id: int, length: int, crc_index: int) -> Callable[[bytes | bytearray], bool]:
    """ok(payload): payload[crc_index] == e2e_crc(data_id, payload, crc_index), generated with
    the byte loop unrolled for payloads of `length` bytes (any other length: e2e_crc)."""
    table = _TABLE
    lines = ["def ok(p):",
             f"    if len(p) != {length}: return p[{crc_index}] == _crc(_ID, p, {crc_index})",
             f"    c = {table[table[0xFF ^ (data_id & 0xFF)] ^ ((data_id >> 8) & 0xFF)]}"]
    lines += [f"    c = _T[c ^ p[{i}]]" for i in range(length) if i != crc_index]
    lines.append(f"    return p[{crc_index}] == c ^ 0xFF")
    ns: dict[str, object] = {"_T": table, "_crc": e2e_crc, "_ID": data_id}
    code = compile("\n".join(lines) + "\n", f"<vecu e2e check {data_id:#x}>", "exec")
    exec(code, ns)  # noqa: S102 (generated from the message's layout)
    return ns["ok"]  # type: ignore[return-value]


class AliveCounterCheck:
    """Receiver side of a 4-bit alive counter: accepts +1 (mod 16); flags repeats and jumps.

    After an error the next counter is accepted as the new reference (resynchronisation).
    """

    def __init__(self, modulo: int = 16, max_delta: int = 1) -> None:
        self.modulo = modulo
        self.max_delta = max_delta
        self._last: int | None = None

    def check(self, counter: int) -> bool:
        last = self._last
        self._last = counter
        if last is None:
            return True
        delta = (counter - last) % self.modulo
        return 1 <= delta <= self.max_delta

    def reset(self) -> None:
        self._last = None
