"""Several ECUs on one bus: the CAN IDs of ECU instance N (`ecu.instance`, docs/live.md).

One rule, used by everyone who sends or reads an ECU's frames: the ECU's diagnostic servers
(UDS, XCP) take their default IDs from it, and the codec moves the ECU's own broadcast frames
(every message its DBCs give the ECU node as a sender) by `ecu_frame_id`. Instance 0 is vecu's
IDs as they always were.

- UDS (ISO 15765-4 Table 5, the OBD ECU IDs): physical request 0x7E0 + N, response 0x7E8 + N;
  the functional request 0x7DF is shared by every ECU.
- XCP on CAN: master 0x7F0 + 2N, slave 0x7F1 + 2N (above the UDS block, 0x7F0-0x7FF for N 0..7).
- The ECU's frames: ID + N * FRAME_STRIDE. 0x60 is the smallest stride above the 0x33-wide block
  of estimates (0x200-0x232) that never lands one instance's estimates on another's ECU_Status /
  ECU_Diag (0x100 above them: no multiple k * 0x60, k = 1..7, lies within 0xCE..0x101), and
  instance 7's last frame (0x5A1) stays below the fault injector's 0x6F0.

The E2E data ID of a protected frame is its CAN ID (vecu.e2e.own_protection), so it moves with
the frame: a receiver that took instance 1's frame for instance 0's would see a CRC error.
"""

from __future__ import annotations

from collections.abc import Mapping

from vecu.errors import ConfigError

MAX_INSTANCE = 7
FRAME_STRIDE = 0x60
ECU_NODE = "VECU"  # the ECU's node name in vecu's DBCs: its messages move with the instance
MAX_STANDARD_ID = 0x7FF
MAX_EXTENDED_ID = 0x1FFF_FFFF

UDS_REQUEST_BASE = 0x7E0
UDS_RESPONSE_BASE = 0x7E8
UDS_FUNCTIONAL_ID = 0x7DF
XCP_MASTER_BASE = 0x7F0
XCP_SLAVE_BASE = 0x7F1


def _check(instance: int) -> int:
    if not 0 <= instance <= MAX_INSTANCE:
        raise ConfigError(f"ECU instance {instance} outside 0..{MAX_INSTANCE}")
    return instance


def uds_ids(instance: int) -> dict[str, int]:
    """ecu.uds.request_id / response_id / functional_id of ECU instance N."""
    n = _check(instance)
    return {"request_id": UDS_REQUEST_BASE + n, "response_id": UDS_RESPONSE_BASE + n,
            "functional_id": UDS_FUNCTIONAL_ID}


def xcp_ids(instance: int) -> dict[str, int]:
    """ecu.xcp.master_id / slave_id of ECU instance N."""
    n = _check(instance)
    return {"master_id": XCP_MASTER_BASE + 2 * n, "slave_id": XCP_SLAVE_BASE + 2 * n}


def ecu_frame_id(frame_id: int, instance: int, extended: bool = False) -> int:
    """The CAN ID of the ECU's frame `frame_id` (its instance-0 ID in the DBC) on instance N
    (ConfigError when it leaves the ID range)."""
    moved = frame_id + _check(instance) * FRAME_STRIDE
    if moved > (MAX_EXTENDED_ID if extended else MAX_STANDARD_ID):
        raise ConfigError(f"ECU frame 0x{frame_id:X} of instance {instance} would be 0x{moved:X}, "
                          f"outside the {'29' if extended else '11'}-bit range")
    return moved


def check_distinct(ids: Mapping[str, int]) -> None:
    """ConfigError naming the first two entries of `ids` (name: CAN ID) that share an ID."""
    seen: dict[int, str] = {}
    for name, can_id in ids.items():
        if can_id in seen:
            raise ConfigError(f"{seen[can_id]} and {name} share the CAN ID 0x{can_id:X}")
        seen[can_id] = name
