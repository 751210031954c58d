"""A message's E2E layout: its `<prefix>_CRC` / `<prefix>_AliveCounter` signals read as the
AUTOSAR E2E Profile 11 header (AUTOSAR_PRS_E2EProtocol, P11: CRC-8 SAE J1850 byte, 4-bit alive
counter in the low nibble of the next byte; vecu.e2e, data ID = the CAN ID)."""

from __future__ import annotations

from dataclasses import dataclass

from cantools.database.can import Message

from vecu.e2e import E2EProtection, own_protection
from vecu.errors import BadFileError


class DbcLoadError(BadFileError):
    """A DBC file that cannot be used: DbcLoadError(path, problem)."""


@dataclass(frozen=True)
class E2ELayout:
    """A message's `<prefix>_CRC` / `<prefix>_AliveCounter` signals and the AUTOSAR profile
    they carry (vecu.e2e.own_protection: P11, data ID = the CAN ID)."""

    crc_signal: str
    counter_signal: str
    crc_byte: int
    protection: E2EProtection


def e2e_layout(message: Message) -> E2ELayout | None:
    """The message's E2E layout, None without a CRC and a counter signal; DbcLoadError when
    the two are not P11's header."""
    crc = next((s for s in message.signals if s.name.endswith("_CRC")), None)
    counter = next((s for s in message.signals if s.name.endswith("_AliveCounter")), None)
    if crc is None or counter is None:
        return None
    at = crc.start // 8
    if (crc.length != 8 or crc.start % 8 != 0 or counter.byte_order != "little_endian"
            or counter.start != 8 * (at + 1) or counter.length != 4 or at + 2 > message.length):
        raise DbcLoadError(None, f"{message.name}: E2E signals {crc.name} / {counter.name} must "
                           "be AUTOSAR P11's header: an 8-bit CRC byte, the 4-bit counter in the "
                           "low nibble of the next byte")
    protection = own_protection(message.frame_id & 0xFFFF)
    if at:
        protection = E2EProtection("P11", data_id=message.frame_id & 0xFFFF, offset=at)
    return E2ELayout(crc.name, counter.name, at, protection)
